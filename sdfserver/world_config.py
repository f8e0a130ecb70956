"""What a world is: its size, chunking, cap and algorithms, validated before a world is made.

Kept apart from ``World`` so that code which only describes worlds (requests, settings,
storage) does not need the device side.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sdfserver.errors import InvalidInput
from sdfserver.geometry import Box, Vec3

CHUNK_SIZES = (8, 16, 32, 64, 128)
MAX_SIDE_VOX = 2048  # exact.cl: at most 128 segments of 16 elements per line
# The most voxels a world can have: past 2^31, so every world-sized number is 64-bit,
# on the host and in the kernels (kernels/include/sdf_common.h).
MAX_WORLD_VOXELS = MAX_SIDE_VOX ** 3


@dataclass(frozen=True)
class Focus:
    """A box of chunks: ``center - size // 2 <= c < center - size // 2 + size``."""

    center: Vec3
    size: Vec3

    def chunk_box(self) -> Box:
        lo = tuple(c - s // 2 for c, s in zip(self.center, self.size))
        return Box(lo, tuple(l + s for l, s in zip(lo, self.size)))


def _is_int(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, np.integer))


@dataclass(frozen=True)
class WorldConfig:
    size: Vec3  # (sx, sy, sz) voxels
    chunk_size: int = 16
    max_distance: int = 255
    algorithm: str = "exact"
    focus: Focus | None = None
    lod_algorithm: str = "jfa"

    def validated(self) -> "WorldConfig":
        # The registry imports the kernels' host side; only validation needs it.
        from sdfserver.algorithms import get_algorithm

        size = self.size
        if not isinstance(size, (tuple, list)) or len(size) != 3 or not all(_is_int(v) for v in size):
            raise InvalidInput(f"size must be three integers [sx, sy, sz], got {size!r}")
        if self.chunk_size not in CHUNK_SIZES:
            raise InvalidInput(f"chunk_size must be one of {CHUNK_SIZES}, got {self.chunk_size!r}")
        for v in size:
            if v <= 0 or v % self.chunk_size:
                raise InvalidInput(
                    f"size {list(size)} must be positive whole multiples of chunk_size {self.chunk_size}"
                )
            if v > MAX_SIDE_VOX:
                raise InvalidInput(f"each side must be at most {MAX_SIDE_VOX} voxels, got {list(size)}")
        if not _is_int(self.max_distance) or not 1 <= self.max_distance <= 255:
            raise InvalidInput(f"max_distance must be an integer 1..255, got {self.max_distance!r}")
        get_algorithm(self.algorithm)
        get_algorithm(self.lod_algorithm)
        if self.focus is not None:
            for name, v in (("center", self.focus.center), ("size", self.focus.size)):
                if len(v) != 3 or not all(_is_int(c) for c in v):
                    raise InvalidInput(f"focus {name} must be three integers (chunks), got {v!r}")
            if any(s <= 0 for s in self.focus.size):
                raise InvalidInput(f"focus size must be positive, got {list(self.focus.size)}")
        return replace(self, size=tuple(int(v) for v in size))

    @property
    def chunks(self) -> Vec3:
        return tuple(v // self.chunk_size for v in self.size)


__all__ = ["CHUNK_SIZES", "MAX_SIDE_VOX", "MAX_WORLD_VOXELS", "Focus", "WorldConfig"]
