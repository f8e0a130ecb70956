"""A 65536 x 256 x 65536 sparse world (2^40 voxels) with edits far apart: memory follows the
stored bricks, each edit's work follows its own region, and the field around each edit is
scipy's."""

from __future__ import annotations

import numpy as np
from references import oracle_distance

from sdfserver.edits import parse_edits
from sdfserver.geometry import Box
from sdfserver.sparse.world import SparseWorld
from sdfserver.world import WorldConfig

SIZE = (65536, 256, 65536)
CAP = 15


def test_edits_far_apart_in_a_huge_world(gpu, rng):
    world = SparseWorld(gpu, WorldConfig(SIZE, 32, CAP, storage="sparse"))
    try:
        centres = [(int(rng.integers(40, 65496)), int(rng.integers(40, 216)), int(rng.integers(40, 65496)))
                   for _ in range(5)] + [(65530, 250, 65530), (3, 2, 65533)]  # world corners too
        batch = [{"op": "sphere", "center": list(c), "radius": float(rng.uniform(2, 9)),
                  "colour": int(rng.integers(1, 256))} for c in centres]
        batch.append({"op": "voxels", "voxels": [[c[0] + 5, c[1], c[2], 77] for c in centres[:3]]})
        world.apply_edits(parse_edits(batch))
        result = world.recompute()
        # Each edit is its own region (the voxels join their sphere's), a few bricks a side.
        assert len(result.regions) == len({c for c in centres})
        assert all(max(r.shape_xyz) <= 32 * 3 for r in result.regions)
        assert world.stored_bricks <= sum(r.volume for r in result.regions) // 32 ** 3
        assert world.device_bytes < 64 << 20
        assert world.scratch is not None and world._scratch_sizes_held[0] <= max(
            world.scratch_box(r).volume for r in result.regions)
        for c in centres:  # each neighbourhood, reaching past the cap: against scipy on its voxels
            box = Box(tuple(max(0, v - 48) for v in c), tuple(min(s, v + 48) for v, s in zip(c, SIZE)))
            field = world.read_field(box)
            assert (field & 0xFF).any()
            assert np.array_equal(field >> 8, oracle_distance((field & 0xFF).astype(np.uint8), CAP))
        # Far from every edit the world reads as air at the cap.
        far = world.read_field(Box((30000, 100, 30000), (30040, 120, 30040)))
        assert (far == CAP << 8).all() or any(
            Box((30000, 100, 30000), (30040, 120, 30040)).overlaps(r) for r in result.regions)
        # Erasing one edit frees its bricks and touches only its own region.
        stored = world.stored_bricks
        first = batch[0]
        c = centres[0]  # the sphere and the voxel beside it (which may hold its bricks alone)
        world.apply_edits(parse_edits([{"op": "sphere", "center": first["center"], "radius": first["radius"],
                                        "colour": 0}, {"op": "voxels", "voxels": [[c[0] + 5, c[1], c[2], 0]]}]))
        again = world.recompute()
        assert len(again.regions) == 1 and max(again.regions[0].shape_xyz) <= 32 * 3
        assert world.stored_bricks < stored
    finally:
        world.release()
