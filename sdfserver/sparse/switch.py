"""A sparse world's switch of metric or sign: every brick within the cap of a solid recomputed.

A dense world's switch marks the whole world dirty; a sparse world is never recomputed whole, and
its field around a region cannot seed the region in the new metric (it still holds the old one's
values). So the pending edits are first written in the old metric (a recompute), then the bricks
that can hold anything but air at the cap in the new metric — every brick of a kept block that is
not air, grown by the cap — are recomputed tile by tile from the voxels alone, each tile in a halo
of the cap (the terrain generator's tiling). Air at the cap reads the same in both metrics, and a
Euclidean distance is never above the Manhattan one, so no brick outside those can change.

Room is reserved first: every implicit brick of the tiles may become stored, so the pools are
grown for that many before anything changes, and a switch that cannot fit is refused whole
(DeviceMemoryExceeded, 507). The tiles' regions are published with the step's recompute.
"""

from __future__ import annotations

from sdfserver.algorithms import get_algorithm
from sdfserver.geometry import Box, merge_regions
from sdfserver.sparse.table import AIR
from sdfserver.sparse.terrain import TILE_VOX
from sdfserver.world_config import WorldConfig


def switch_field(world, config: WorldConfig) -> None:
    """Give ``world`` (a SparseWorld) ``config``'s metric and sign and recompute what they change."""
    if world.dirty or world.pending:
        world.switched_regions.extend(world.recompute().regions)  # the pending edits, in the old field
    tiles = tiles_near_solids(world, config.max_distance)
    world.pool.reserve(sum(int((world.table.get(t) < 0).sum()) for t in tiles))  # raises, nothing changed
    old, world.config = world.config, config
    brick, cap = world.brick, config.max_distance
    regions = [Box(tuple(v * brick for v in t.lo), tuple(v * brick for v in t.hi)) for t in tiles]
    try:
        world._ensure_scratch(max((world.scratch_box(r, halo=True).volume for r in regions), default=0))
    except BaseException:
        world.config = old
        raise
    algorithm = get_algorithm(config.algorithm)
    for region in regions:  # one loop over tiles
        world._compute_region(region, algorithm, cap, halo=True)
    world.gpu.queue.finish()
    world.switched_regions.extend(regions)


def tiles_near_solids(world, cap: int) -> list[Box]:
    """Boxes of bricks, at most TILE_VOX voxels a side, covering every brick within ``cap`` of a
    brick that is not air: one loop over kept blocks, then over the merged boxes' tiles."""
    brick = world.brick
    reach = -(-cap // brick)
    bricks = Box.of_size(world.config.chunks)
    near = [box.grow(reach).intersect(bricks) for box, codes in world.table.items() if (codes != AIR).any()]
    tile = max(1, TILE_VOX // brick)
    out = []
    for box in merge_regions(near, max_regions=1 << 20):
        for z in range(box.lo[2], box.hi[2], tile):
            for y in range(box.lo[1], box.hi[1], tile):
                for x in range(box.lo[0], box.hi[0], tile):
                    out.append(Box((x, y, z), (min(x + tile, box.hi[0]), min(y + tile, box.hi[1]),
                                               min(z + tile, box.hi[2]))))
    return out
