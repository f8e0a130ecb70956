"""What a world's stored field values mean, decoded on the host (docs/algorithms.md, "Metrics and
signs"; kernels/include/field_source.h is the device side).

- manhattan: uint16 ``(distance << 8) | colour``; the colour byte is the voxel's value.
- euclidean: uint16, the squared distance between voxel centres; the colour is the voxel's value.
- signed (either metric): a solid voxel stores its distance to the nearest air voxel, and its sign
  is the voxel's: solid (value != 0) is negative. Unsigned, a solid stores 0.

``GET .../field?format=distance`` answers ``distances``: uint8 for unsigned Manhattan worlds (as
always), int16 for signed Manhattan ones, float32 for Euclidean ones.
"""

from __future__ import annotations

import numpy as np

from sdfserver.world_config import WorldConfig


def distance_dtype(config: WorldConfig) -> np.dtype:
    if config.euclidean:
        return np.dtype(np.float32)
    return np.dtype(np.int16) if config.signed else np.dtype(np.uint8)


def needs_voxels(config: WorldConfig) -> bool:
    """Whether decoding distances reads the voxels too (the sign of a signed Euclidean field)."""
    return config.euclidean and config.signed


def packed_content(config: WorldConfig) -> str:
    """What ``format=packed`` carries, named in reads and stream messages."""
    return "squared_distance" if config.euclidean else "distance_colour"


def distances(field: np.ndarray, config: WorldConfig, voxels: np.ndarray | None = None) -> np.ndarray:
    """The distances, in voxels, of stored ``field`` values (``voxels``: the same box's voxels,
    needed where ``needs_voxels``)."""
    if config.euclidean:
        out = np.sqrt(field.astype(np.float32))
        if config.signed:
            np.negative(out, out=out, where=voxels != 0)
        return out
    magnitude = field >> 8
    if not config.signed:
        return magnitude.astype(np.uint8)
    out = magnitude.astype(np.int16)
    np.negative(out, out=out, where=(field & 0xFF) != 0)
    return out
