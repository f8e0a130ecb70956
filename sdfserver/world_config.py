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
BORDERS = ("exact", "padded")
STORAGES = ("dense", "sparse")
# A sparse world stores only the bricks (chunks) that are neither all air at the cap nor all solid
# of one colour, so its sides are bounded by its brick table, not by one buffer: x and z up to
# 65536 voxels, y up to 4096. What an edit recomputes is still a dense scratch box, whose sides
# exact.cl bounds by MAX_SIDE_VOX.
MAX_SPARSE_SIDE_XZ_VOX = 65536
MAX_SPARSE_SIDE_Y_VOX = 4096
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


@dataclass(frozen=True)
class TerrainSpec:
    """A generated terrain (sdfserver/sparse/terrain.py, kernels/terrain.cl), for sparse worlds."""

    seed: int = 0
    base: float | None = None  # the height the surface rolls around; default 0.4 of the world's height
    amplitude: float | None = None  # the surface lies within base ± amplitude; default 0.15 of the height
    overhang: float = 8.0  # how far 3-D noise moves the surface up or down (overhangs, arches)
    cave_depth: float = 40.0  # caves lie at most this far below the surface
    kind: str = "terrain"

    def validated(self, size_y: int) -> "TerrainSpec":
        base = 0.4 * size_y if self.base is None else self.base
        amplitude = 0.15 * size_y if self.amplitude is None else self.amplitude
        if self.kind != "terrain":
            raise InvalidInput(f"generate kind must be 'terrain', got {self.kind!r}")
        if not _is_int(self.seed) or not 0 <= self.seed < 1 << 32:
            raise InvalidInput(f"terrain seed must be an integer 0..2^32-1, got {self.seed!r}")
        for name, v, lo, hi in (("base", base, 0, size_y), ("amplitude", amplitude, 0, size_y),
                                ("overhang", self.overhang, 0, 64), ("cave_depth", self.cave_depth, 0, 256)):
            if not isinstance(v, (int, float, np.integer, np.floating)) or isinstance(v, bool) \
                    or not np.isfinite(v) or not lo <= v <= hi:
                raise InvalidInput(f"terrain {name} must be a number {lo}..{hi}, got {v!r}")
        return TerrainSpec(int(self.seed), float(base), float(amplitude), float(self.overhang),
                           float(self.cave_depth))


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
    # "exact": chunk borders are exact (chunks are units of dirtiness, not of computation).
    # "padded": the dissertation's §4.2.1 — each chunk computed alone, everything outside it
    # solid; an edit recomputes only the chunks it touches. Not for algorithm "exact".
    borders: str = "exact"
    # "dense": one buffer of every voxel. "sparse": a brick table and pools of stored bricks
    # (sdfserver/sparse/); borders exact, no focus.
    storage: str = "dense"
    generate: TerrainSpec | None = None  # sparse only: the world starts as this terrain, not as air

    def validated(self) -> "WorldConfig":
        # The registry imports the kernels' host side; only validation needs it.
        from sdfserver.algorithms import get_algorithm

        size = self.size
        if not isinstance(size, (tuple, list)) or len(size) != 3 or not all(_is_int(v) for v in size):
            raise InvalidInput(f"size must be three integers [sx, sy, sz], got {size!r}")
        if self.chunk_size not in CHUNK_SIZES:
            raise InvalidInput(f"chunk_size must be one of {CHUNK_SIZES}, got {self.chunk_size!r}")
        if self.storage not in STORAGES:
            raise InvalidInput(f"storage must be one of {list(STORAGES)}, got {self.storage!r}")
        for v in size:
            if v <= 0 or v % self.chunk_size:
                raise InvalidInput(
                    f"size {list(size)} must be positive whole multiples of chunk_size {self.chunk_size}"
                )
        if self.storage == "dense" and max(size) > MAX_SIDE_VOX:
            raise InvalidInput(f"each side must be at most {MAX_SIDE_VOX} voxels, got {list(size)} "
                               f"(storage 'sparse' allows {MAX_SPARSE_SIDE_XZ_VOX} along x and z, "
                               f"{MAX_SPARSE_SIDE_Y_VOX} along y)")
        if self.storage == "sparse":
            if max(size[0], size[2]) > MAX_SPARSE_SIDE_XZ_VOX or size[1] > MAX_SPARSE_SIDE_Y_VOX:
                raise InvalidInput(f"a sparse world's sides must be at most {MAX_SPARSE_SIDE_XZ_VOX} along x and "
                                   f"z and {MAX_SPARSE_SIDE_Y_VOX} along y, got {list(size)}")
            if self.focus is not None or self.borders != "exact":
                raise InvalidInput("a sparse world has exact borders and no focus")
        generate = self.generate
        if generate is not None:
            if self.storage != "sparse":
                raise InvalidInput("generate is for storage 'sparse'")
            if not isinstance(generate, TerrainSpec):
                raise InvalidInput(f"generate must be a terrain, got {generate!r}")
            generate = generate.validated(size[1])
        if not _is_int(self.max_distance) or not 1 <= self.max_distance <= 255:
            raise InvalidInput(f"max_distance must be an integer 1..255, got {self.max_distance!r}")
        algorithm, lod_algorithm = get_algorithm(self.algorithm), get_algorithm(self.lod_algorithm)
        if self.borders not in BORDERS:
            raise InvalidInput(f"borders must be one of {list(BORDERS)}, got {self.borders!r}")
        if self.borders == "padded":
            used = [algorithm] + ([lod_algorithm] if self.focus is not None else [])
            for a in used:
                if not getattr(a, "supports_padding", False):
                    raise InvalidInput(f"borders 'padded' is not available for algorithm {a.name!r}; "
                                       f"use borders 'exact' or one of {padded_algorithms()}")
        if self.focus is not None:
            for name, v in (("center", self.focus.center), ("size", self.focus.size)):
                if len(v) != 3 or not all(_is_int(c) for c in v):
                    raise InvalidInput(f"focus {name} must be three integers (chunks), got {v!r}")
            if any(s <= 0 for s in self.focus.size):
                raise InvalidInput(f"focus size must be positive, got {list(self.focus.size)}")
        return replace(self, size=tuple(int(v) for v in size), generate=generate)

    @property
    def chunks(self) -> Vec3:
        return tuple(v // self.chunk_size for v in self.size)

    @property
    def floods(self) -> bool:
        """Whether an algorithm this world runs needs jump flooding's seed buffers."""
        from sdfserver.algorithms import get_algorithm

        used = [self.algorithm] + ([self.lod_algorithm] if self.focus is not None else [])
        return any(getattr(get_algorithm(a), "seed_scratch", False) for a in used)


def padded_algorithms() -> list[str]:
    from sdfserver.algorithms import ALGORITHMS

    return sorted(n for n, a in ALGORITHMS.items() if getattr(a, "supports_padding", False))


__all__ = ["BORDERS", "CHUNK_SIZES", "MAX_SIDE_VOX", "MAX_SPARSE_SIDE_XZ_VOX", "MAX_SPARSE_SIDE_Y_VOX",
           "MAX_WORLD_VOXELS", "STORAGES", "Focus", "TerrainSpec", "WorldConfig"]
