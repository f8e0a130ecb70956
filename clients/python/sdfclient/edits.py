"""Edit operations in their wire form.

    client.edit(world_id, [sphere((32, 32, 32), 6, colour=0xE0),
                           box((0, 0, 0), (64, 4, 64), colour=0x1C),
                           voxels(np.array([[1, 2, 3, 255]])),
                           erase_sphere((32, 32, 32), 3)])

Colour 0 erases. Boxes are half-open (``min <= p < max``); a voxel ``p`` is
in a sphere when ``|p - center| <= radius``. Explicit voxels travel as one
``uint16`` N x 4 array (x, y, z, colour), a binary blob on the wire.
"""

from __future__ import annotations

from typing import Any, Iterable, Sequence

import numpy as np


def sphere(center: Sequence[float], radius: float, colour: int = 255) -> dict:
    return {"op": "sphere", "center": [float(c) for c in center], "radius": float(radius), "colour": int(colour)}


def box(min: Sequence[int], max: Sequence[int], colour: int = 255) -> dict:  # noqa: A002 - the wire's names
    return {"op": "box", "min": [int(v) for v in min], "max": [int(v) for v in max], "colour": int(colour)}


def erase_sphere(center: Sequence[float], radius: float) -> dict:
    return sphere(center, radius, colour=0)


def erase_box(min: Sequence[int], max: Sequence[int]) -> dict:  # noqa: A002
    return box(min, max, colour=0)


def voxels(array: Any) -> dict:
    """Explicit voxels: an (N, 4) array of x, y, z, colour, sent as uint16."""
    array = np.asarray(array)
    if array.ndim != 2 or array.shape[1] != 4:
        raise ValueError(f"voxels must be an N x 4 array (x, y, z, colour), got shape {array.shape}")
    if array.dtype.kind not in "iu":
        raise ValueError(f"voxels must be integers, got {array.dtype}")
    if array.size and (array.min() < 0 or array.max() > 0xFFFF):
        raise ValueError("voxel coordinates and colours must fit in uint16")
    return {"op": "voxels", "voxels": np.ascontiguousarray(array, dtype=np.uint16)}


def normalize(edits: Iterable[Any]) -> list[dict]:
    """Edits as wire dicts: accepts the helpers' dicts and bare N x 4 arrays."""
    out = []
    for e in edits:
        if isinstance(e, np.ndarray):
            out.append(voxels(e))
        elif isinstance(e, dict) and e.get("op") == "voxels" and not isinstance(e.get("voxels"), np.ndarray):
            out.append(voxels(np.asarray(e["voxels"], dtype=np.int64).reshape(-1, 4)))
        elif isinstance(e, dict):
            out.append(e)
        else:
            raise TypeError(f"an edit is a dict (see sdfclient.edits) or an N x 4 array, got {type(e).__name__}")
    return out


__all__ = ["box", "erase_box", "erase_sphere", "normalize", "sphere", "voxels"]
