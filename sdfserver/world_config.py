"""What a world is: its size, chunking, cap and algorithms, validated before a world is made.

Kept apart from ``World`` so that code which only describes worlds (requests, settings,
storage) does not need the device side.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sdfserver.errors import InvalidInput
from sdfserver.geometry import Box, Vec3
from sdfserver.incoming import short

CHUNK_SIZES = (8, 16, 32, 64, 128)
MAX_SIDE_VOX = 2048  # exact.cl: at most 128 segments of 16 elements per line
BORDERS = ("exact", "padded")
STORAGES = ("dense", "sparse")
# "manhattan": the dissertation's capped L1 distance, packed (distance << 8) | colour.
# "euclidean": the exact distance between voxel centres, stored as its square (docs/algorithms.md,
# "Metrics and signs").
METRICS = ("manhattan", "euclidean")
PALETTE_COLOURS = 255  # a voxel's value 1..255 is its palette index; 0 is air
MAX_WORLD_UNITS = 1e9  # |origin| and voxel_size * side stay well inside float32's exact range
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
            raise InvalidInput(f"generate kind must be 'terrain', got {short(self.kind)}")
        if not _is_int(self.seed) or not 0 <= self.seed < 1 << 32:
            raise InvalidInput(f"terrain seed must be an integer 0..2^32-1, got {short(self.seed)}")
        for name, v, lo, hi in (("base", base, 0, size_y), ("amplitude", amplitude, 0, size_y),
                                ("overhang", self.overhang, 0, 64), ("cave_depth", self.cave_depth, 0, 256)):
            if not isinstance(v, (int, float, np.integer, np.floating)) or isinstance(v, bool) \
                    or not np.isfinite(v) or not lo <= v <= hi:
                raise InvalidInput(f"terrain {name} must be a number {lo}..{hi}, got {short(v)}")
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
    metric: str = "manhattan"  # METRICS
    # True: a solid voxel carries minus its distance to the nearest air voxel (outside the world
    # is air), so the field changes sign across every surface. The stored magnitude is the same
    # kind of number as on air; the sign is the voxel's (solid or not).
    signed: bool = False
    voxel_size: float = 1.0  # world units per voxel (queries in world units)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)  # world units of voxel (0, 0, 0)'s low corner
    # 255 (r, g, b) colours, voxel value v drawn as palette[v - 1]; None: RGB332 (the dissertation's).
    palette: tuple[tuple[int, int, int], ...] | None = None

    def validated(self) -> "WorldConfig":
        # The registry imports the kernels' host side; only validation needs it.
        from sdfserver.algorithms import get_algorithm

        size = self.size
        if not isinstance(size, (tuple, list)) or len(size) != 3 or not all(_is_int(v) for v in size):
            raise InvalidInput(f"size must be three integers [sx, sy, sz], got {short(size)}")
        if self.chunk_size not in CHUNK_SIZES:
            raise InvalidInput(f"chunk_size must be one of {CHUNK_SIZES}, got {short(self.chunk_size)}")
        if self.storage not in STORAGES:
            raise InvalidInput(f"storage must be one of {list(STORAGES)}, got {short(self.storage)}")
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
                raise InvalidInput(f"generate must be a terrain, got {short(generate)}")
            generate = generate.validated(size[1])
        if not _is_int(self.max_distance) or not 1 <= self.max_distance <= 255:
            raise InvalidInput(f"max_distance must be an integer 1..255, got {short(self.max_distance)}")
        algorithm, lod_algorithm = get_algorithm(self.algorithm), get_algorithm(self.lod_algorithm)
        if self.borders not in BORDERS:
            raise InvalidInput(f"borders must be one of {list(BORDERS)}, got {short(self.borders)}")
        if self.borders == "padded":
            used = [algorithm] + ([lod_algorithm] if self.focus is not None else [])
            for a in used:
                if not getattr(a, "supports_padding", False):
                    raise InvalidInput(f"borders 'padded' is not available for algorithm {a.name!r}; "
                                       f"use borders 'exact' or one of {padded_algorithms()}")
        if self.focus is not None:
            for name, v in (("center", self.focus.center), ("size", self.focus.size)):
                if len(v) != 3 or not all(_is_int(c) for c in v):
                    raise InvalidInput(f"focus {name} must be three integers (chunks), got {short(v)}")
            if any(s <= 0 for s in self.focus.size):
                raise InvalidInput(f"focus size must be positive, got {list(self.focus.size)}")
        self._validate_field_options(algorithm, lod_algorithm)
        return replace(self, size=tuple(int(v) for v in size), generate=generate,
                       voxel_size=float(self.voxel_size), origin=tuple(float(v) for v in self.origin),
                       palette=_palette(self.palette))

    def _validate_field_options(self, algorithm, lod_algorithm) -> None:
        """metric, signed, voxel_size and origin; which algorithms and options each allows."""
        if self.metric not in METRICS:
            raise InvalidInput(f"metric must be one of {list(METRICS)}, got {short(self.metric)}")
        if not isinstance(self.signed, (bool, np.bool_)):
            raise InvalidInput(f"signed must be true or false, got {short(self.signed)}")
        v = self.voxel_size
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v) \
                or not 0 < v or v * max(self.size) > MAX_WORLD_UNITS:
            raise InvalidInput(f"voxel_size must be a finite positive number (world units per voxel, at most "
                               f"{MAX_WORLD_UNITS:g} across the world), got {short(v)}")
        o = self.origin
        if not isinstance(o, (tuple, list)) or len(o) != 3 or any(
                isinstance(c, bool) or not isinstance(c, (int, float, np.integer, np.floating))
                or not np.isfinite(c) or abs(c) > MAX_WORLD_UNITS for c in o):
            raise InvalidInput(f"origin must be three finite numbers (world units, |value| <= "
                               f"{MAX_WORLD_UNITS:g}), got {o!r}")
        if self.metric == "manhattan" and not self.signed:
            return
        what = f"metric {self.metric!r}" + (", signed" if self.signed else "")
        if algorithm.name != "exact":
            raise InvalidInput(f"a world with {what} computes its field with algorithm 'exact' only "
                               f"(got {algorithm.name!r}): the others are Manhattan and unsigned")
        if self.focus is not None:
            raise InvalidInput(f"a world with {what} has no focus: the level-of-detail algorithms are "
                               f"Manhattan and unsigned")
        if self.borders != "exact":
            raise InvalidInput(f"a world with {what} has borders 'exact'")

    @property
    def euclidean(self) -> bool:
        return self.metric == "euclidean"
    @property
    def chunks(self) -> Vec3:
        return tuple(v // self.chunk_size for v in self.size)

    @property
    def floods(self) -> bool:
        """Whether an algorithm this world runs needs jump flooding's seed buffers."""
        from sdfserver.algorithms import get_algorithm

        used = [self.algorithm] + ([self.lod_algorithm] if self.focus is not None else [])
        return any(getattr(get_algorithm(a), "seed_scratch", False) for a in used)


def rgb332_palette() -> np.ndarray:
    """The default palette: value v's RGB332 bits expanded to 8-bit channels, as the renderer
    always drew them ((255, 3) uint8, row v - 1)."""
    v = np.arange(1, 256, dtype=np.uint32)
    r, g, b = (v >> 5) & 7, (v >> 2) & 7, v & 3
    return np.stack([r * 255 // 7, g * 255 // 7, b * 255 // 3], axis=1).astype(np.uint8)


def _palette(palette) -> tuple[tuple[int, int, int], ...] | None:
    if palette is None:
        return None
    if isinstance(palette, np.ndarray):
        palette = palette.tolist()
    if not isinstance(palette, (list, tuple)) or len(palette) != PALETTE_COLOURS:
        raise InvalidInput(f"palette must be a list of {PALETTE_COLOURS} [r, g, b] colours (voxel values 1..255), "
                           f"got {type(palette).__name__} of length {len(palette) if hasattr(palette, '__len__') else '?'}")
    out = []
    for i, c in enumerate(palette):
        if not isinstance(c, (list, tuple)) or len(c) != 3 or not all(_is_int(v) and 0 <= v <= 255 for v in c):
            raise InvalidInput(f"palette[{i}] must be [r, g, b] with integers 0..255, got {short(c)}")
        out.append(tuple(int(v) for v in c))
    return tuple(out)


def padded_algorithms() -> list[str]:
    from sdfserver.algorithms import ALGORITHMS

    return sorted(n for n, a in ALGORITHMS.items() if getattr(a, "supports_padding", False))


__all__ = ["BORDERS", "CHUNK_SIZES", "METRICS", "PALETTE_COLOURS", "MAX_SIDE_VOX", "MAX_SPARSE_SIDE_XZ_VOX", "MAX_SPARSE_SIDE_Y_VOX",
           "MAX_WORLD_VOXELS", "STORAGES", "Focus", "TerrainSpec", "WorldConfig", "rgb332_palette"]
