"""Many worlds in one step (issue 31): the step enqueues every touched world's recompute and
waits for the device once; each world's field is what it would be recomputed alone."""

from __future__ import annotations

import numpy as np

from sdfserver.edits import parse_edits
from sdfserver.engine import Engine, EngineLimits
from sdfserver.engine.commands import ApplyEdits, CreateWorld, Read
from sdfserver.world import WorldConfig
from sdfserver.world_factory import make_world

CONFIGS = [dict(metric="manhattan"), dict(metric="euclidean"), dict(metric="manhattan", signed=True),
           dict(metric="euclidean", signed=True), dict(storage="sparse"), dict(metric="euclidean", storage="sparse")]


def test_worlds_recomputed_in_one_step_equal_each_alone(gpu):
    engine = Engine(gpu, EngineLimits(max_worlds=16))
    try:
        rng = np.random.default_rng()
        ids = []
        for options in CONFIGS:
            future = engine.submit(CreateWorld(WorldConfig(size=(32, 16, 24), chunk_size=8, max_distance=6,
                                                           **options)))
            engine.step()
            ids.append(future.result()["id"])
        batches = []
        for _ in range(3):  # three steps, each touching every world
            step_batches = []
            for world_id in ids:
                rows = np.column_stack([rng.integers(0, 16, (20, 3)), rng.integers(0, 256, 20)])
                raw = [{"op": "voxels", "voxels": rows},
                       {"op": "sphere", "center": rng.uniform(0, 16, 3).tolist(), "radius": 3.5,
                        "colour": int(rng.integers(0, 3))}]
                step_batches.append(raw)
                assert engine.submit(ApplyEdits(world_id, parse_edits(raw), raw)) is not None
            engine.step()
            batches.append(step_batches)
        reads = [engine.submit(Read(world_id, "packed")) for world_id in ids]
        engine.step()
        for k, (options, read) in enumerate(zip(CONFIGS, reads)):
            alone = make_world(gpu, WorldConfig(size=(32, 16, 24), chunk_size=8, max_distance=6, **options))
            try:
                for step_batches in batches:
                    alone.apply_edits(parse_edits(step_batches[k]))
                    alone.recompute()
                assert np.array_equal(read.result(timeout=10).array, alone.read_field()), options
            finally:
                alone.release()
    finally:
        engine.stop()


def test_prepared_launches_follow_regions_and_configuration(gpu):
    """A world keeps its recompute's launches prepared and its kernels' arguments set between
    steps (World._launches, gpu/launches.py): whether the dirty regions repeat, move or change
    shape, and across a reconfiguration, every field is the true one."""
    from references import oracle_distance

    from sdfserver.edits import BoxEdit, SphereEdit

    world = make_world(gpu, WorldConfig(size=(32, 16, 24), chunk_size=8, max_distance=5))
    try:
        rng = np.random.default_rng(3)
        places = [(2, 2, 2), (2, 2, 2), (20, 9, 14), (2, 2, 2), (27, 1, 20)]  # repeats, moves and back
        for step in range(12):
            if step == 6:
                world.reconfigure(max_distance=9)
            if step == 9:
                world.reconfigure(max_distance=40)  # every region the whole world
            lo = places[step % len(places)]
            world.apply_edits([BoxEdit(lo, tuple(c + int(rng.integers(1, 4)) for c in lo), int(rng.integers(0, 3))),
                               SphereEdit(tuple(float(c) for c in rng.uniform(0, 16, 3)), 2.5, 1)])
            world.recompute()
            voxels = world.read_voxels()
            expected = oracle_distance(voxels, world.config.max_distance)
            assert np.array_equal((world.read_field() >> 8).astype(np.uint8), expected), f"step {step}"
        assert world.buffers.kernels is not None and len(world.buffers.kernels) > 0
    finally:
        world.release()
