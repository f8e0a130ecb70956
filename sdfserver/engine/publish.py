"""Publishing a recompute: the rewritten chunks that subscribers hold go to their mailboxes."""

from __future__ import annotations

import numpy as np

from sdfserver.engine.mailbox import ChunkKey, Subscription
from sdfserver.errors import InvalidInput, TooLarge
from sdfserver.field_values import distances, needs_voxels
from sdfserver.geometry import Box, Vec3
from sdfserver.world import RecomputeResult, World


def check_subscription_region(region: Box, world_box: Box, max_voxels: int) -> None:
    """A subscription covers whole chunks inside the world, and not too many voxels."""
    if region.empty or not world_box.contains(region):
        raise InvalidInput(f"region {list(region.lo)}..{list(region.hi)} is empty or outside the world "
                           f"{list(world_box.hi)}")
    if region.volume > max_voxels:
        raise TooLarge(f"a subscription of {region.volume} voxels; the limit is {max_voxels}")


def publish(world: World, result: RecomputeResult, subs: list[Subscription]) -> int:
    """Read each recomputed region once, hand each subscriber its chunks; returns chunks merged."""
    merged = 0
    for region in result.regions:
        readers = [s for s in subs if s.region.overlaps(region)]
        if not readers:
            continue
        box = region.intersect(_union([s.region for s in readers]))
        field = world.read_field(box)
        decoded = None
        for sub in readers:
            part = region.intersect(sub.region)
            if not part.empty:
                if sub.format == "distance" and decoded is None:
                    voxels = world.read_voxels(box) if needs_voxels(world.config) else None
                    decoded = distances(field, world.config, voxels)
                chunks = chunks_of(decoded if sub.format == "distance" else field, box.lo, part,
                                   world.config.chunk_size)
                merged += sub.mailbox.put(world.field_version, chunks)
    return merged


def _union(boxes: list[Box]) -> Box:
    out = boxes[0]
    for b in boxes[1:]:
        out = out.union(b)
    return out


def chunks_of(array: np.ndarray, origin: Vec3, part: Box, chunk_size: int) -> dict[ChunkKey, bytes]:
    """Split the chunk-aligned ``part`` of ``array`` (element 0 at ``origin``: the packed field, or
    its distances) into per-chunk bytes.

    This is the step's one loop over chunks.
    """
    block = array[part.slices_zyx(origin)]
    cs = chunk_size
    nz, ny, nx = block.shape
    tiles = block.reshape(nz // cs, cs, ny // cs, cs, nx // cs, cs).transpose(0, 2, 4, 1, 3, 5)
    x0, y0, z0 = (v // cs for v in part.lo)
    return {(x0 + cx, y0 + cy, z0 + cz): tiles[cz, cy, cx].tobytes()
            for cz, cy, cx in np.ndindex(tiles.shape[:3])}
