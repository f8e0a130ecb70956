"""Small worlds side by side in slot pools (gpu/slots.py) and their stacked transform
(sdfserver/stacked.py, Exact.run_slots): the pool's memory comes and goes with its worlds, a
world's writes stay in its slot, and a stacked run gives each world the field scipy gives it,
whichever slots run together, with clean and differently configured neighbours left alone."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver import stacked
from sdfserver.algorithms.exact import Exact
from sdfserver.edits import parse_edits
from sdfserver.engine import Engine, batches
from sdfserver.engine.commands import ApplyEdits, CreateWorld, Read
from sdfserver.field_values import distances
from sdfserver.gpu import slots
from sdfserver.world import World, WorldConfig

from references import apply_edits as apply_reference
from references import oracle_distance

SIZE = (32, 16, 32)  # each buffer a whole number of the sub-buffer alignment (512 bytes on NVIDIA)


def random_batch(rng, size, count=3) -> list[dict]:
    """Solids and air: voxel lists across the world and a sphere that may erase."""
    rows = np.column_stack([rng.integers(0, s, count * 10) for s in size] + [rng.integers(0, 256, count * 10)])
    return [{"op": "voxels", "voxels": rows},
            {"op": "sphere", "center": [float(rng.uniform(0, s)) for s in size],
             "radius": float(rng.uniform(1, 6)), "colour": int(rng.integers(0, 3))}]


def overlapping_boxes(rng, size) -> list[dict]:
    """Two boxes of different colours (one may be air) that overlap."""
    lo = [int(rng.integers(0, s - 4)) for s in size]
    return [{"op": "box", "min": lo, "max": [v + 6 for v in lo], "colour": int(rng.integers(1, 256))},
            {"op": "box", "min": [v + 2 for v in lo], "max": [v + 9 for v in lo], "colour": int(rng.integers(0, 3))}]


def field_of(world: World, expected: np.ndarray) -> np.ndarray:
    return distances(world.read_field(), world.config, expected)


def test_worlds_of_one_size_share_a_pool_that_goes_with_the_last(gpu):
    before = gpu.allocated_bytes
    worlds = [World(gpu, WorldConfig(SIZE, 8)) for _ in range(3)]
    try:
        pools = gpu.slot_pools.pools[SIZE]
        assert len(pools) == 1 and all(w.slot.pool is pools[0] for w in worlds)
        assert sorted(w.slot.index for w in worlds) == [0, 1, 2]
        voxels, field, work, work2 = World.buffer_bytes(WorldConfig(SIZE, 8).validated())[:4]
        assert pools[0].slots == slots.POOL_MAX_SLOTS  # small worlds: as many as a pool may hold
        assert gpu.allocated_bytes - before == (voxels + field + work) * pools[0].slots + 3 * work2
        worlds.pop(1).release()
        assert pools[0].used == 2
        other = World(gpu, WorldConfig((SIZE[0], SIZE[1], 2 * SIZE[2]), 8))  # another size, another pool
        assert other.slot.pool is not pools[0]
        other.release()
    finally:
        for world in worlds:
            world.release()
    assert SIZE not in gpu.slot_pools.pools and gpu.allocated_bytes == before


def test_a_freed_slot_starts_the_next_world_empty(gpu, rng):
    """A world made in the slot another left holds air and the cap, not what the other held."""
    worlds = [World(gpu, WorldConfig(SIZE, 8)) for _ in range(2)]
    try:
        left = worlds.pop(0)
        left.apply_edits(parse_edits(random_batch(rng, SIZE, count=20)))
        left.recompute()
        index = left.slot.index
        left.release()
        worlds.append(World(gpu, WorldConfig(SIZE, 8)))
        assert worlds[-1].slot.index == index
        assert not worlds[-1].read_voxels().any()
        assert (field_of(worlds[-1], None) == 255).all()
    finally:
        for world in worlds:
            world.release()


def test_a_pool_is_not_made_from_a_large_share_of_the_budget(gpu, monkeypatch):
    monkeypatch.setattr(slots, "POOL_BUDGET_SHARE", 0.0)
    world = World(gpu, WorldConfig(SIZE, 8))
    try:
        assert world.slot is None
        world.apply_edits(parse_edits([{"op": "box", "min": [1, 1, 1], "max": [4, 4, 4], "colour": 7}]))
        world.recompute()
        assert field_of(world, None).min() == 0
    finally:
        world.release()


def test_a_stacked_run_gives_each_world_its_own_field(gpu, rng):
    """Seven worlds in one pool: four edited and stacked, one edited but recomputed with fim, one
    clean, and one with another cap, which runs apart; every field equals scipy's, over rounds of
    edits that add and erase."""
    configs = [dict()] * 4 + [dict(algorithm="fim"), dict(), dict(max_distance=40)]
    worlds = [World(gpu, WorldConfig(SIZE, 8, **c)) for c in configs]
    expected = [np.zeros(SIZE[::-1], np.uint8) for _ in worlds]
    try:
        assert len({id(w.slot.pool) for w in worlds}) == 1
        edited = worlds[:5] + worlds[6:]
        for _ in range(3):
            for world in edited:
                batch = random_batch(rng, SIZE)
                world.apply_edits(parse_edits(batch))
                apply_reference(expected[worlds.index(world)], batch)
            assert [w.stacking_job() is not None for w in worlds] == [True] * 4 + [False, False, True]
            pending = stacked.begin_stacked(gpu, dict(enumerate(worlds)))
            assert sorted(pending) == [0, 1, 2, 3]  # the cap-40 world alone: its own launches
            results = [pending[i].finish() for i in range(4)] + [worlds[4].recompute(), worlds[6].recompute()]
            shares = [r.algorithms["exact"].device_ms for r in results[:4]]
            assert len(set(shares)) == 1  # each counts a quarter of the run's kernel time
            for r in results[:4]:  # the share's sums, made once for the run, are each world's
                assert r.device_ms == shares[0] == pytest.approx(sum(r.kernel_ms)) and r.device_ms > 0
                assert r.iterations == r.algorithms["exact"].iterations
            for world, voxels in zip(worlds, expected):
                assert not world.dirty
                cap = world.config.max_distance
                assert np.array_equal(field_of(world, voxels), oracle_distance(voxels, cap))
                assert np.array_equal(world.read_voxels(), voxels)
    finally:
        for world in worlds:
            world.release()


def test_only_worlds_whose_dirty_regions_are_the_whole_world_join_a_stacked_run(gpu):
    """Under a cap below the world's side a brush's region is part of the world: its own
    launches; under a cap of the side or more, or after a whole-world change, it joins."""
    small, large = (World(gpu, WorldConfig(SIZE, 8, max_distance=cap)) for cap in (2, 32))
    try:
        brush = parse_edits([{"op": "sphere", "center": [4.0, 4.0, 4.0], "radius": 1.5, "colour": 3}])
        for world in (small, large):
            assert world.stacking_job() is None  # nothing dirty
            world.apply_edits(brush)
        assert small.stacking_job() is None and large.stacking_job() is not None
        small.mark_all_dirty()
        assert small.stacking_job() is not None
    finally:
        small.release()
        large.release()


def test_a_stacked_run_reaches_every_slot_of_a_large_pool(gpu, rng):
    """Forty worlds in one pool, every third left clean: one stacked run covers slots in every
    32-bit lane of its slot mask, each world gets scipy's field and the clean ones keep theirs."""
    worlds = [World(gpu, WorldConfig(SIZE, 8)) for _ in range(40)]
    expected = [np.zeros(SIZE[::-1], np.uint8) for _ in worlds]
    try:
        assert len({id(w.slot.pool) for w in worlds}) == 1 and worlds[0].slot.pool.slots >= 40
        for round in range(2):
            edited = [i for i in range(len(worlds)) if (i + round) % 3]
            for i in edited:
                batch = random_batch(rng, SIZE)
                worlds[i].apply_edits(parse_edits(batch))
                apply_reference(expected[i], batch)
            pending = stacked.begin_stacked(gpu, {i: worlds[i] for i in edited})
            assert sorted(pending) == edited and max(worlds[i].slot.index for i in edited) >= 32
            for p in pending.values():
                p.finish()
            for world, voxels in zip(worlds, expected):
                assert np.array_equal(field_of(world, voxels), oracle_distance(voxels, 255))
    finally:
        for world in worlds:
            world.release()


def test_many_pooled_worlds_in_one_step_equal_one_by_one(gpu, rng, monkeypatch):
    """An engine step that edits ten worlds (two pools of eight slots) stacks their transforms, a
    run per pool; another engine that takes the same batches a world a step gets the same fields,
    and both equal scipy's."""
    monkeypatch.setattr(slots, "POOL_MAX_SLOTS", 8)
    stacked_slots, pooled_brushes = [], []
    real = Exact.run_slots
    monkeypatch.setattr(Exact, "run_slots", lambda self, gpu, pool, at, job: stacked_slots.append(len(at)) or
                        real(self, gpu, pool, at, job))
    real_brushes = batches.enqueue_pooled_brushes
    monkeypatch.setattr(batches, "enqueue_pooled_brushes", lambda gpu, pooled: pooled_brushes.append(len(pooled)) or
                        real_brushes(gpu, pooled))
    together, alone = Engine(gpu), Engine(gpu)
    try:
        ids = {}
        for engine in (together, alone):
            futures = [engine.submit(CreateWorld(WorldConfig(SIZE, 8))) for _ in range(10)]  # two pools
            engine.step()
            ids[engine] = [f.result()["id"] for f in futures]
        expected = [np.zeros(SIZE[::-1], np.uint8) for _ in range(10)]
        for round in range(3):
            # two batches a world: the second's overlapping box wins where they meet
            sent = [[random_batch(rng, SIZE), overlapping_boxes(rng, SIZE)] for _ in range(10)]
            for voxels, pair in zip(expected, sent):
                for batch in pair:
                    apply_reference(voxels, batch)
            for world_id, pair in zip(ids[together], sent):
                for batch in pair:
                    together.submit(ApplyEdits(world_id, parse_edits(batch), batch))
            together.step()
            for world_id, pair in zip(ids[alone], sent):
                for batch in pair:
                    alone.submit(ApplyEdits(world_id, parse_edits(batch), batch))
                alone.step()
        assert stacked_slots and sorted(set(stacked_slots)) == [2, 8]  # a run per pool
        assert pooled_brushes and max(pooled_brushes) == 10
        for engine in (together, alone):
            reads = [engine.submit(Read(world_id, "distance")) for world_id in ids[engine]]
            engine.step()
            voxel_reads = [engine.submit(Read(world_id, "voxels")) for world_id in ids[engine]]
            engine.step()
            for read, voxel_read, voxels in zip(reads, voxel_reads, expected):
                assert np.array_equal(voxel_read.result().array, voxels)
                assert np.array_equal(read.result().array, oracle_distance(voxels, 255))
    finally:
        together.stop()
        alone.stop()
