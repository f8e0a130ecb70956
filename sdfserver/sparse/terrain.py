"""A generated terrain for a sparse world (``POST /v1/worlds`` with ``generate: {kind: "terrain",
...}``): kernels/terrain.cl says what the ground is; here is how it is built without ever
holding the world densely.

1. ``terrain_columns``: per brick column, the lowest and highest surface height.
2. Per brick column, the band of bricks that may be neither all stone nor all air at the cap:
   from below the deepest cave or dirt, to the cap above the highest surface within the cap's
   reach of its neighbours. Bricks below are solid stone, bricks above air at the cap: both
   implicit, written into the brick table only. Their sum bounds the stored bricks, and the pools
   are reserved for it before anything else is allocated (DeviceMemoryExceeded, 507).
3. Tile by tile (``TILE_VOX`` wide along x and z, the band's height): the tile and a halo of the
   cap are generated into the scratch box, the world's algorithm runs on it in halo mode (its
   field exact from voxels alone), and the tile's bricks are classified and scattered exactly as
   after an edit. One loop over tiles.
4. The pools shrink to the bricks stored, the scratch box is released.
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl as cl

from sdfserver.world import field_defines
from sdfserver.algorithms import RegionJob, WorldBuffers, get_algorithm
from sdfserver.algorithms.base import grid, int4
from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.geometry import Box
from sdfserver.sparse import kernels
from sdfserver.sparse.table import AIR, solid_code
from sdfserver.world_config import TerrainSpec

STONE = 0x92  # kernels/terrain.cl
DIRT_DEPTH = 6
TILE_VOX = 512
STRIP_COLUMNS = 1 << 14  # brick columns bounded per launch


def _neighbourhood_max(a: np.ndarray, reach: int) -> np.ndarray:
    """Each entry's maximum over the (2 reach + 1)^2 entries around it (a loop over offsets)."""
    padded = np.pad(a, reach, mode="edge")
    out = a.copy()
    for dz in range(2 * reach + 1):
        for dx in range(2 * reach + 1):
            np.maximum(out, padded[dz:dz + a.shape[0], dx:dx + a.shape[1]], out=out)
    return out


def brick_bands(world, params: TerrainSpec) -> tuple[np.ndarray, np.ndarray]:
    """Per brick column (z, x): the first brick that may be stored and the one past the last.

    Strips of brick columns in turn (one loop over strips): once the bands found so far — each
    column's own, before its neighbours widen it — cannot fit the pools, DeviceMemoryExceeded,
    so a world too large to store costs the strips that fill the memory, not its whole area."""
    gpu, cfg, brick = world.gpu, world.config, world.brick
    cx, by, cz = cfg.chunks
    rows = max(1, STRIP_COLUMNS // cx)
    bounds = np.empty((cz, cx, 2), dtype=np.int32)
    below = math.ceil(params.overhang) + math.ceil(max(params.cave_depth, DIRT_DEPTH)) + 1
    above = math.ceil(params.overhang) + cfg.max_distance + 1
    buffer = cl.Buffer(gpu.context, cl.mem_flags.WRITE_ONLY, size=rows * cx * 8)
    least = 0
    try:
        for z0 in range(0, cz, rows):
            n = min(rows, cz - z0)
            gsize, lsize = grid((cx, n, 1), (8, 8, 1))
            gpu.programs.kernel("terrain.cl", "terrain_columns")(
                gpu.queue, gsize, lsize, buffer, np.int32(cx), np.int32(z0), np.int32(n), np.int32(brick),
                np.uint32(params.seed), np.float32(params.base), np.float32(params.amplitude))
            cl.enqueue_copy(gpu.queue, bounds[z0:z0 + n], buffer, is_blocking=True)
            strip = bounds[z0:z0 + n]
            lo = np.clip((strip[..., 0] - below) // brick, 0, by)
            least += int((np.clip(-(-(strip[..., 1] + above) // brick), 0, by) - lo).clip(0).sum())
            world.pool.check_room(least)
    finally:
        buffer.release()
    reach = -(-cfg.max_distance // brick)
    top = _neighbourhood_max(bounds[..., 1], reach) + above
    lo = np.clip((bounds[..., 0] - below) // brick, 0, by)
    hi = np.clip(-(-top // brick), 0, by)
    return lo, np.maximum(lo, hi)


def generate_terrain(world, params: TerrainSpec) -> None:
    """Fill an empty sparse world with terrain (module docstring)."""
    params = params.validated(world.config.size[1])
    cfg, gpu, brick = world.config, world.gpu, world.brick
    lo, hi = brick_bands(world, params)
    world.pool.reserve(int((hi - lo).sum()))  # raises, nothing allocated, when they cannot fit
    tile = max(1, TILE_VOX // brick)
    while True:  # the widest tiles whose scratch box fits beside the pools
        tiles = _tiles(world, lo, hi, tile)
        try:
            world._ensure_scratch(max((s.volume for _, _, _, s in tiles), default=0))
            break
        except DeviceMemoryExceeded:
            if tile == 1:
                raise  # the world that called releases its pools
            tile //= 2
    algorithm = get_algorithm(cfg.algorithm)
    for columns, y0, y1, box in tiles:  # one loop over tiles
        if y0 > 0:
            world.table.set(Box(columns.lo, (columns.hi[0], y0, columns.hi[2])),
                            np.full((columns.shape_zyx[0], y0, columns.shape_zyx[2]), solid_code(STONE), np.int32))
        if y1 > y0:
            region = Box((columns.lo[0] * brick, y0 * brick, columns.lo[2] * brick),
                         (columns.hi[0] * brick, y1 * brick, columns.hi[2] * brick))
            _build_tile(world, algorithm, region, box, params)
    gpu.queue.finish()
    world.pool.shrink()
    world._release_scratch()


def _tiles(world, lo: np.ndarray, hi: np.ndarray, tile: int) -> list[tuple[Box, int, int, Box]]:
    """Tiles of ``tile`` brick columns a side: (their columns, first brick, brick past the last,
    the scratch box of their band and its halo)."""
    brick, cap, (_, by, _) = world.brick, world.config.max_distance, world.config.chunks
    halo_x = -(-cap // 8) * 8  # the work box's rows stay aligned to 8
    tiles = []
    for tz in range(0, lo.shape[0], tile):
        for tx in range(0, lo.shape[1], tile):
            y0, y1 = int(lo[tz:tz + tile, tx:tx + tile].min()), int(hi[tz:tz + tile, tx:tx + tile].max())
            columns = Box((tx, 0, tz), (min(tx + tile, lo.shape[1]), by, min(tz + tile, lo.shape[0])))
            region = Box((columns.lo[0] * brick, y0 * brick, columns.lo[2] * brick),
                         (columns.hi[0] * brick, y1 * brick, columns.hi[2] * brick))
            tiles.append((columns, y0, y1, _halo_box(world, region, halo_x, cap) if y1 > y0 else region))
    return tiles


def _halo_box(world, region: Box, halo_x: int, cap: int) -> Box:
    return Box((region.lo[0] - halo_x, region.lo[1] - cap, region.lo[2] - cap),
               (region.hi[0] + halo_x, region.hi[1] + cap, region.hi[2] + cap)).intersect(world.world_box)


def _build_tile(world, algorithm, region: Box, box: Box, params: TerrainSpec) -> None:
    gpu, s, brick, cap = world.gpu, world.scratch, world.brick, world.config.max_distance
    gsize, lsize = grid(box.shape_xyz)
    gpu.programs.kernel("terrain.cl", "terrain_voxels")(
        gpu.queue, gsize, lsize, s.voxels, int4(box.shape_xyz), int4(box.lo), np.uint32(params.seed),
        np.float32(params.base), np.float32(params.amplitude), np.float32(params.overhang),
        np.float32(params.cave_depth))
    local = Box(tuple(r - b for r, b in zip(region.lo, box.lo)), tuple(r - b for r, b in zip(region.hi, box.lo)))
    view = WorldBuffers(box.shape_xyz, s.voxels, s.field, s.work, s.work2)
    algorithm.run(gpu, RegionJob.halo_region(view, local, cap))
    mixed, first = kernels.classify(gpu, s.voxels, s.field, box.shape_xyz, local, cap, brick, world.classify_results,
                                    field_defines(world.config))
    codes = np.where(first == 0, AIR, solid_code(first)).astype(np.int32)
    codes[mixed] = world.pool.take(int(mixed.sum()))
    bricks = region.chunk_range(brick)
    kernels.scatter(gpu, world.pool, s.voxels, s.field, box, region, bricks, codes, brick)
    world.table.set(bricks, codes)
