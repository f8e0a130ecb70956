"""Readers that walk the field themselves — frames, picks, point queries — see a sparse world
exactly as the dense world fed the same batches: the same kernels, reading bricks through the
device brick table (kernels/include/field_source.h)."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver.edits import parse_edits
from sdfserver.engine.query import run_query
from sdfserver.render import Camera, RenderOptions, Renderer
from sdfserver.sparse.terrain import generate_terrain
from sdfserver.world_config import TerrainSpec
from sdfserver.sparse.world import SparseWorld
from sdfserver.world import World, WorldConfig

from .conftest import random_batch

SIZE, BRICK, CAP = (96, 64, 128), 16, 9


@pytest.fixture
def world_pair(gpu, rng):
    dense = World(gpu, WorldConfig(SIZE, BRICK, CAP))
    # Pool segments of 48 bricks: readers cross segments (the first batch reserves all 192 bricks).
    sparse = SparseWorld(gpu, WorldConfig(SIZE, BRICK, CAP, storage="sparse"), segment_bricks=48)
    floor = [{"op": "box", "min": [0, 0, 0], "max": [96, 20, 128], "colour": 0x92}]  # whole solid bricks
    for batch in [floor] + [random_batch(rng, SIZE, BRICK) for _ in range(4)]:
        for world in (dense, sparse):
            world.apply_edits(parse_edits(batch))
            world.recompute()
    assert any(isinstance(b, int) or (b <= -2).any() for b in sparse.table.blocks.values())  # solid bricks
    assert (sparse.table.get(sparse.world_box.chunk_range(BRICK)) == -1).any()  # and air ones
    assert len(sparse.pool.segments) >= 2
    yield dense, sparse
    dense.release()
    sparse.release()


@pytest.mark.parametrize("options", [RenderOptions(), RenderOptions(ambient_occlusion=True, shadows=True)])
def test_frames_and_picks_equal_the_dense_worlds(gpu, world_pair, options):
    dense, sparse = world_pair
    renderer = Renderer(gpu)
    reads = []
    for position, target in [((-40.0, 90.0, -30.0), (48.0, 10.0, 64.0)), ((48.0, 30.0, 64.0), (0.0, 0.0, 128.0)),
                             ((150.0, 20.0, 200.0), (40.0, 25.0, 30.0))]:
        camera = Camera.look_at(position, target, width=160, height=120).validated()
        a = renderer.render(dense, camera, RenderOptions(**{**options.__dict__, "cursor": (80.0, 60.0)}), stats=True)
        b = renderer.render(sparse, camera, RenderOptions(**{**options.__dict__, "cursor": (80.0, 60.0)}), stats=True)
        assert np.array_equal(a.pixels, b.pixels)
        reads.append((int(a.reads.sum()), int(b.reads.sum())))
        assert (a.pick is None) == (b.pick is None) and (a.pick is None or a.pick.voxel == b.pick.voxel)
        assert (a.pixels[..., :3] != [0x9C, 0xC8, 0xF0]).any(axis=-1).mean() > 0.05  # the frame shows ground
    # Rays cross implicit air bricks in steps longer than the cap: fewer reads for the same frames.
    assert sum(b for _, b in reads) < sum(a for a, _ in reads)


def test_point_queries_equal_the_dense_worlds(world_pair, rng):
    dense, sparse = world_pair
    points = rng.uniform(0, 1, (500, 3)) * np.array(SIZE)
    for kind, rows in (("points", points), ("spheres", np.column_stack([points, rng.uniform(0, 3, 500)])),
                       ("rays", np.column_stack([points, rng.normal(size=(500, 3)), np.full(500, 200.0)]))):
        a, b = run_query(dense, kind, rows), run_query(sparse, kind, rows)
        for name in a.arrays:  # a ray jumps further across implicit bricks: its t may round differently
            np.testing.assert_allclose(a.arrays[name], b.arrays[name], rtol=0, atol=1e-3 if kind == "rays" else 0,
                                       err_msg=f"{kind} {name}")
        if kind == "points":
            distances = a.arrays["distances"]
            assert (distances < CAP).any() and (distances == 0).any()


def test_a_terrain_renders_from_above(gpu):
    world = SparseWorld(gpu, WorldConfig((256, 128, 256), 32, 15, storage="sparse"))
    try:
        generate_terrain(world, TerrainSpec(seed=3))
        camera = Camera.look_at((-60.0, 160.0, -60.0), (128.0, 40.0, 128.0), width=128, height=96).validated()
        frame = Renderer(gpu).render(world, camera, RenderOptions(ambient_occlusion=True, shadows=True))
        ground = (frame.pixels[..., :3] != [0x9C, 0xC8, 0xF0]).any(axis=-1)
        assert 0.2 < ground.mean() < 1.0
    finally:
        world.release()
