"""Work refused at the door (a recompute over the server's limit), how a step busy past its
budget shows, and what a stop does to the requests it cuts off."""

from __future__ import annotations

import time

import numpy as np
import pytest
from prometheus_client import generate_latest

from sdfserver import brushes, recompute_cost
from sdfserver.edits import REPLAY_LIMITS, EditLimits, edit_bounds, parse_edits, validate_batch
from sdfserver.engine import Engine, EngineLimits
from sdfserver.engine.commands import CreateWorld, Describe, OnDevice, Read, Reconfigure
from sdfserver.errors import InvalidInput, NotReady, RecomputeCostExceeded, TooLarge
from sdfserver.settings import Settings
from sdfserver.world import World, WorldConfig
from sdfserver.world_config import Focus

from references import apply_edits as apply_reference


def config(side, **kw) -> WorldConfig:
    return WorldConfig(size=(side,) * 3, **kw).validated()


def test_the_cost_model_admits_the_defaults_and_refuses_what_stalled_an_engine():
    limit = Settings().max_recompute_voxel_visits
    assert recompute_cost.estimate(config(2048, chunk_size=32)).visits <= limit  # the largest dense world
    assert recompute_cost.estimate(config(128)).visits <= limit
    brute = recompute_cost.estimate(config(128, algorithm="brute"))
    assert brute.visits == 128 ** 6 and brute.visits > limit  # every voxel scans the whole world
    assert recompute_cost.estimate(config(1024, algorithm="fim")).visits > limit
    assert recompute_cost.estimate(config(1024, algorithm="jfa")).visits > limit
    assert recompute_cost.estimate(config(256, algorithm="brute", borders="padded")).visits > limit
    # a small cap shrinks brute force's window, padded borders shrink it to the chunk
    assert recompute_cost.visits_per_voxel("brute", config(128, algorithm="brute", max_distance=2)) == 5 ** 3
    assert recompute_cost.visits_per_voxel("brute", config(128, algorithm="brute", borders="padded")) == 16 ** 3
    # outside a focus, the level-of-detail algorithm
    focused = config(256, focus=Focus((2, 2, 2), (4, 4, 4)), lod_algorithm="jfa")
    inside = 64 ** 3
    assert recompute_cost.estimate(focused).visits == inside * 3 + (256 ** 3 - inside) * 27 * 8


def test_the_message_names_the_estimate_and_the_limit():
    with pytest.raises(RecomputeCostExceeded) as info:
        recompute_cost.check(config(128, algorithm="brute"), 30_000_000_000)
    message = str(info.value)
    assert "brute at 128³, cap 255 would scan 4.4e12 voxel pairs" in message
    assert "this server allows 3e10" in message
    assert info.value.code == "recompute_cost_exceeded" and isinstance(info.value, InvalidInput)
    recompute_cost.check(config(128, algorithm="brute"), None)  # no limit


@pytest.fixture
def engine(gpu):
    engine = Engine(gpu, EngineLimits(max_recompute_voxel_visits=10 ** 8))
    yield engine
    engine.stop()


def run(engine, command):
    """Step until ``command`` is answered (a world's commands wait while it recomputes in pieces)."""
    future = engine.submit(command)
    engine.step()
    while not future.done():
        engine.step()
    return future


def test_a_create_over_the_limit_is_refused_and_nothing_is_made(engine):
    refused = run(engine, CreateWorld(WorldConfig(size=(64, 64, 64), algorithm="brute")))
    with pytest.raises(RecomputeCostExceeded, match="brute at 64³, cap 255 would scan 6.9e10"):
        refused.result()
    assert engine.worlds == {}
    world_id = run(engine, CreateWorld(WorldConfig(size=(64, 64, 64), algorithm="brute", max_distance=2))).result()["id"]
    assert engine.worlds[world_id].config.max_distance == 2


def test_a_reconfiguration_over_the_limit_changes_nothing(engine):
    world_id = run(engine, CreateWorld(WorldConfig(size=(64, 64, 64), chunk_size=16))).result()["id"]
    before = engine.worlds[world_id].config
    version = run(engine, Describe(world_id)).result()["field_version"]
    with pytest.raises(RecomputeCostExceeded, match="brute at 64³"):
        run(engine, Reconfigure(world_id, {"algorithm": "brute"})).result()
    assert engine.worlds[world_id].config == before
    assert not engine.worlds[world_id].dirty
    assert run(engine, Describe(world_id)).result()["field_version"] == version
    # a small enough cap makes it affordable; and what does not recompute is never refused
    run(engine, Reconfigure(world_id, {"algorithm": "brute", "max_distance": 2})).result()
    assert engine.worlds[world_id].config.algorithm == "brute"
    tight = EngineLimits(max_recompute_voxel_visits=1)
    engine.table.limits = tight
    run(engine, Reconfigure(world_id, {"voxel_size": 2.0})).result()
    assert engine.worlds[world_id].config.voxel_size == 2.0


def busy_gauge(engine) -> float:
    for line in generate_latest(engine.metrics.registry).decode().splitlines():
        if line.startswith("sdfserver_engine_busy_seconds "):
            return float(line.split()[1])
    raise KeyError("sdfserver_engine_busy_seconds")


def test_a_step_past_its_budget_says_what_it_does(gpu):
    engine = Engine(gpu, EngineLimits(busy_step_ms=50.0))
    world_id = run(engine, CreateWorld(WorldConfig(size=(16, 16, 16), chunk_size=8))).result()["id"]
    seen = {}

    def slow():
        seen["early"] = engine.busy()
        time.sleep(0.1)
        seen["late"] = engine.busy()
        seen["gauge"] = busy_gauge(engine)

    engine.submit(OnDevice(slow))
    engine.submit(Read(world_id, "voxels"))
    engine.step()
    assert seen["early"] is None  # under the budget
    assert seen["late"]["phase"] == "serve" and seen["late"]["worlds"] == [world_id]
    assert seen["late"]["busy_ms"] >= 100 and seen["gauge"] >= 0.1
    assert engine.busy() is None and busy_gauge(engine) == 0.0  # the step is over


def test_a_stop_fails_the_reads_still_waiting_with_503(gpu):
    engine = Engine(gpu)
    world_id = run(engine, CreateWorld(WorldConfig(size=(16, 16, 16), chunk_size=8))).result()["id"]
    engine.start(warm_up=False)
    waiting = engine.submit(Read(world_id, "distance", min_version=5, deadline=time.monotonic() + 60))
    time.sleep(0.2)
    assert not waiting.done()
    engine.stop()
    with pytest.raises(NotReady, match="shutting down"):
        waiting.result(timeout=5)


def whole_world_boxes(n: int, side: int) -> list[dict]:
    return [{"op": "box", "min": [0, 0, 0], "max": [side] * 3, "colour": 1 + i % 255} for i in range(n)]


def test_a_batch_whose_brushes_cover_too_much_is_refused():
    dims = (128, 128, 128)
    heavy = parse_edits(whole_world_boxes(1024, 128))  # 2.1e9 voxels together
    with pytest.raises(TooLarge, match="1024 boxes and spheres cover 2,147,483,648 voxels together"):
        validate_batch(heavy, dims, EditLimits())
    validate_batch(heavy[:512], dims, EditLimits())  # 1.07e9: the limit itself
    validate_batch(heavy, dims, REPLAY_LIMITS)  # what was logged is replayed whatever the limit
    # the world once is always allowed; a brush clipped to the world counts what it covers there
    small = EditLimits(max_brush_voxels_per_batch=1000)
    validate_batch(heavy[:1], dims, small)
    validate_batch(parse_edits([{"op": "box", "min": [-10 ** 6] * 3, "max": [10 ** 6] * 3, "colour": 1}]), dims, small)
    with pytest.raises(TooLarge):
        validate_batch(heavy[:2], dims, small)
    spheres = parse_edits([{"op": "sphere", "center": [64, 64, 64], "radius": 4, "colour": 1}] * 2)
    validate_batch(spheres, dims, small)  # 2 x 9^3 = 1,458 voxels: over 1,000, but less than the world
    centred = parse_edits([{"op": "sphere", "center": [4, 4, 4], "radius": 4, "colour": 1}] * 2)
    with pytest.raises(TooLarge, match="cover 1,024 voxels"):  # each clipped to the 8^3 world
        validate_batch(centred, (8, 8, 8), small)


def test_brushes_a_later_box_covers_are_not_launched_and_the_voxels_are_the_same(gpu, monkeypatch):
    raw = [{"op": "sphere", "center": [8, 8, 8], "radius": 5, "colour": 3},  # hidden by the next box
           {"op": "box", "min": [0, 0, 0], "max": [16, 16, 16], "colour": 4},
           {"op": "box", "min": [2, 2, 2], "max": [9, 9, 9], "colour": 5},  # hidden by the box after it
           {"op": "box", "min": [1, 1, 1], "max": [12, 12, 12], "colour": 6},
           {"op": "sphere", "center": [4, 4, 4], "radius": 3, "colour": 7},  # a later sphere hides nothing
           {"op": "box", "min": [3, 3, 3], "max": [30, 30, 30], "colour": 0},
           {"op": "sphere", "center": [3, 3, 3], "radius": 2, "colour": 8}]
    edits = parse_edits(raw)
    boxed = [(e, edit_bounds(e, (32, 32, 32), 1)[0]) for e in edits]
    assert [e.colour for e, _ in brushes.visible(boxed)] == [4, 6, 7, 0, 8]
    launched = []
    real = brushes.enqueue_brush

    monkeypatch.setattr(brushes, "CULL_PER_PAIR_VOXELS", 0)
    world = World(gpu, WorldConfig(size=(32, 32, 32), chunk_size=8, max_distance=8))
    try:
        world.apply_edits(edits)
        expected = np.zeros((32, 32, 32), np.uint8)
        apply_reference(expected, raw)
        assert np.array_equal(world.read_voxels(), expected)
        rng = np.random.default_rng(31)
        for _ in range(5):  # random nests of boxes and spheres
            batch = []
            for _ in range(40):
                lo = rng.integers(-4, 28, 3)
                hi = lo + rng.integers(1, 36, 3)
                batch.append({"op": "box", "min": lo.tolist(), "max": hi.tolist(), "colour": int(rng.integers(0, 256))}
                             if rng.random() < 0.7 else
                             {"op": "sphere", "center": lo.tolist(), "radius": float(rng.integers(0, 12)),
                              "colour": int(rng.integers(0, 256))})
            world.apply_edits(parse_edits(batch))
            apply_reference(expected, batch)
            assert np.array_equal(world.read_voxels(), expected)
        # 1,024 whole-world boxes: one launch of the last box for each launch's worth
        monkeypatch.setattr(brushes, "enqueue_brush", lambda *a, **k: launched.append(a[4]) or real(*a, **k))
        world.apply_edits(parse_edits(whole_world_boxes(1024, 32)))
        assert len(launched) == 1024 // 256 and all(b.volume == 32 ** 3 for b in launched)
        assert (world.read_voxels() == 1 + 1023 % 255).all()
    finally:
        world.release()
