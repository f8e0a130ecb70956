"""The engine without HTTP: step() driven by hand, the journal hook, run_on_device, mailboxes."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pyopencl as cl
import pytest

from sdfserver.edits import parse_edits
from sdfserver.engine import Engine, EngineLimits, Mailbox, Subscription
from sdfserver.engine.commands import (
    ApplyEdits, CreateWorld, DeleteWorld, Describe, OnDevice, Read, Subscribe,
)
from sdfserver.errors import InvalidEdit, NotFound, NotReady, SdfServerError, TooLarge, VersionNotReached
from sdfserver.geometry import Box
from sdfserver.world import WorldConfig

from references import oracle_distance as oracle
from server_process import checkout_env

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def engine(gpu):
    engine = Engine(gpu, EngineLimits(max_worlds=4))
    yield engine
    engine.stop()


def create(engine: Engine, size=(16, 16, 16), cap=5) -> str:
    future = engine.submit(CreateWorld(WorldConfig(size=size, chunk_size=8, max_distance=cap)))
    engine.step()
    return future.result()["id"]


def edits(engine, world_id, raw):
    return engine.submit(ApplyEdits(world_id, parse_edits(raw), raw))


def test_step_applies_each_batch_alone_and_recomputes_each_world_once(engine):
    a, b = create(engine), create(engine)
    rng = np.random.default_rng()
    rows = np.column_stack([rng.integers(0, 16, (30, 3)), rng.integers(1, 256, 30)])
    good1 = edits(engine, a, [{"op": "voxels", "voxels": rows}])
    bad = edits(engine, a, [{"op": "box", "min": [0, 0, 0], "max": [16, 16, 16], "colour": 1},
                            {"op": "voxels", "voxels": [[16, 0, 0, 1]]}])
    good2 = edits(engine, a, [{"op": "box", "min": [2, 2, 2], "max": [5, 5, 5], "colour": 9}])
    other = edits(engine, b, [{"op": "sphere", "center": [8, 8, 8], "radius": 3, "colour": 4}])
    missing = edits(engine, "nope", [{"op": "sphere", "center": [8, 8, 8], "radius": 3, "colour": 4}])
    field = engine.submit(Read(a, "distance"))
    report = engine.step()
    assert (good1.result(), good2.result(), other.result()) == (1, 2, 1)
    with pytest.raises(InvalidEdit):
        bad.result()
    with pytest.raises(NotFound):
        missing.result()
    assert report.applied_batches == 3 and report.rejected_batches == 2
    assert set(report.recomputed) == {a, b}
    expected = np.zeros((16, 16, 16), np.uint8)
    expected[rows[:, 2], rows[:, 1], rows[:, 0]] = rows[:, 3]
    expected[2:5, 2:5, 2:5] = 9
    result = field.result()
    assert result.version == 2
    np.testing.assert_array_equal(result.array, oracle(expected, 5))


class RecordingJournal:
    def __init__(self, fail_on_version: int | None = None):
        self.calls = []
        self.sync_starts = []  # len(calls) at each start_syncs
        self.waits = []  # len(calls) at each wait_durable
        self.fail_on_version = fail_on_version

    def record_create(self, world_id, config, owner=None):
        self.calls.append(("create", world_id, config))

    def record_batches(self, world_id, first_version, batches):
        versions = range(first_version, first_version + len(batches))
        if self.fail_on_version in versions:
            self.fail_on_version = None  # fails once
            raise OSError("disk full")
        self.calls.extend(("batch", world_id, v, edits) for v, edits in zip(versions, batches))

    def start_syncs(self, wait=True):
        self.sync_starts.append(len(self.calls))

    def wait_durable(self, timeout_s):
        self.waits.append(len(self.calls))
        return True

    def record_delete(self, world_id):
        self.calls.append(("delete", world_id))

    def record_config(self, world_id, config):
        self.calls.append(("config", world_id, config))

    def wants_snapshot(self, world_id):
        return False

    def record_snapshot(self, world_id, version, config, voxels, ready):
        raise AssertionError("wants_snapshot said no")

    def epoch_of(self, world_id):
        return 1

    def fenced(self, world_id):
        return False

    def forget(self, world_id):
        raise AssertionError("never fenced")


def test_journal_records_before_acknowledging(gpu):
    journal = RecordingJournal(fail_on_version=3)
    engine = Engine(gpu, journal=journal)
    world_id = create(engine)
    assert journal.calls == [("create", world_id, {"size": [16, 16, 16], "chunk_size": 8, "max_distance": 5,
                                                   "algorithm": "exact", "focus": None, "lod_algorithm": "jfa",
                                                   "borders": "exact", "storage": "dense",
                                                   "generate": None, "metric": "manhattan", "signed": False,
                                                   "voxel_size": 1.0, "origin": [0.0, 0.0, 0.0],
                                                   "palette": None})]
    raw = [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2], "colour": 3}]
    raw2 = [{"op": "sphere", "center": [8, 8, 8], "radius": 2, "colour": 4}]
    first, bad, second = (edits(engine, world_id, raw), edits(engine, world_id, [
        {"op": "voxels", "voxels": [[16, 0, 0, 1]]}]), edits(engine, world_id, raw2))
    seen_done = []
    original = journal.record_batches

    def record_and_look(world, first_version, batches):
        seen_done.append((first.done(), second.done()))
        original(world, first_version, batches)

    journal.record_batches = record_and_look
    engine.step()
    assert (first.result(), second.result()) == (1, 2) and seen_done == [(False, False)]
    with pytest.raises(InvalidEdit):
        bad.result()  # invalid batches never reach the journal
    assert journal.calls[1:] == [("batch", world_id, 1, raw), ("batch", world_id, 2, raw2)]
    failing = edits(engine, world_id, raw)
    engine.step()
    with pytest.raises(OSError):
        failing.result()  # not journaled: not applied, not acknowledged
    assert len(journal.calls) == 3
    third = edits(engine, world_id, raw)
    gone = engine.submit(DeleteWorld(world_id))
    engine.step()
    assert third.result() == 3 and gone.result() is None
    assert journal.calls[-2][:3] == ("batch", world_id, 3) and journal.calls[-1] == ("delete", world_id)
    assert journal.sync_starts == [3, 4]  # once after each step's batches; none when none was recorded
    engine.stop()


def test_a_step_waits_for_its_acknowledgements_only_when_nothing_else_is_queued(gpu):
    journal = RecordingJournal()
    engine = Engine(gpu, journal=journal)
    world_id = create(engine)
    raw = [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2], "colour": 3}]
    edits(engine, world_id, raw)
    engine.step()
    assert journal.waits == [2]  # after the batch's record
    record = journal.record_batches

    def record_while_another_comes(*args):
        record(*args)
        engine.submit(Describe(world_id))

    journal.record_batches = record_while_another_comes
    edits(engine, world_id, raw)
    engine.step()
    engine.step()  # the description that came
    assert journal.waits == [2]
    engine.stop()


def test_min_version_waits_then_answers(engine):
    world_id = create(engine)
    read = engine.submit(Read(world_id, "distance", Box((0, 0, 0), (4, 4, 4)), min_version=1,
                              deadline=float("inf")))
    report = engine.step()
    assert not read.done() and report.waiting == 1
    edits(engine, world_id, [{"op": "box", "min": [0, 0, 0], "max": [1, 1, 1], "colour": 3}])
    engine.step()
    assert read.result().version == 1 and read.result().array[0, 0, 0] == 0
    expired = engine.submit(Read(world_id, "field", None, min_version=5, deadline=0.0))
    engine.step()
    with pytest.raises(VersionNotReached):
        expired.result()


def test_limits(engine):
    with pytest.raises(TooLarge):
        big = engine.submit(CreateWorld(WorldConfig(size=(2048, 2048, 2048))))
        engine.step()
        big.result()
    ids = [create(engine) for _ in range(4)]
    fifth = engine.submit(CreateWorld(WorldConfig(size=(16, 16, 16), chunk_size=8)))
    engine.step()
    with pytest.raises(TooLarge):
        fifth.result()
    assert len(set(ids)) == 4 and all(len(i) >= 8 for i in ids)


def test_subscriptions_get_only_changed_chunks_merged(engine):
    world_id = create(engine, size=(32, 32, 32), cap=3)
    sub = Subscription(world_id, Box((0, 0, 0), (32, 32, 16)), "distance")
    done = engine.submit(Subscribe(sub))
    engine.step()
    done.result()
    initial = sub.mailbox.take()
    assert initial.version == 0 and len(initial.chunks) == 4 * 4 * 2
    assert all(np.frombuffer(c, np.uint8).tolist() == [3] * 512 for c in initial.chunks.values())
    # Two steps the subscriber does not read: merged, newest wins.
    edits(engine, world_id, [{"op": "voxels", "voxels": [[1, 1, 1, 5]]}])
    engine.step()
    edits(engine, world_id, [{"op": "voxels", "voxels": [[1, 1, 1, 0], [30, 1, 1, 5]]}])
    engine.step()
    edits(engine, world_id, [{"op": "voxels", "voxels": [[30, 30, 30, 5]]}])  # outside the region
    engine.step()
    update = sub.mailbox.take()
    assert update.version == 2
    assert set(update.chunks) == {(0, 0, 0), (3, 0, 0)}
    assert np.frombuffer(update.chunks[(0, 0, 0)], np.uint8).reshape(8, 8, 8)[1, 1, 1] == 3
    assert np.frombuffer(update.chunks[(3, 0, 0)], np.uint8).reshape(8, 8, 8)[1, 1, 6] == 0
    assert sub.mailbox.merged_chunks == 1 and sub.mailbox.take() is None
    engine.unsubscribe(sub)
    edits(engine, world_id, [{"op": "voxels", "voxels": [[2, 2, 2, 5]]}])
    engine.step()
    assert sub.mailbox.take() is None


def test_mailbox_notifies_once_per_pending_update():
    calls = []
    box = Mailbox(lambda: calls.append(1))
    box.put(1, {(0, 0, 0): b"a", (1, 0, 0): b"b"})
    box.put(2, {(0, 0, 0): b"c"})
    assert calls == [1] and box.pending_chunks == 2 and box.pending_bytes == 2
    update = box.take()
    assert update.version == 2 and update.chunks == {(0, 0, 0): b"c", (1, 0, 0): b"b"}
    box.put(3, {(2, 0, 0): b"d"})
    assert calls == [1, 1]


def test_thread_run_on_device_and_device_loss(gpu):
    engine = Engine(gpu)
    engine.start(warm_up=False)

    async def scenario():
        while not engine.ready:
            await asyncio.sleep(0.01)
        name = await engine.run_on_device(lambda: threading.current_thread().name)
        world = await engine.create_world(WorldConfig(size=(16, 16, 16), chunk_size=8, max_distance=4))
        version = await engine.apply_edits(world["id"], parse_edits(
            [{"op": "box", "min": [0, 0, 0], "max": [3, 3, 3], "colour": 1}]), [])
        field = await engine.read(world["id"], "distance", min_version=version)

        def lose_device():
            raise cl.RuntimeError("device lost")

        waiting = engine.submit(Read(world["id"], "distance", min_version=99, deadline=float("inf")))
        with pytest.raises(NotReady, match="device lost"):
            await engine.run_on_device(lose_device)
        return name, field, waiting

    name, field, waiting = asyncio.run(scenario())
    assert name == "sdfserver-engine" and field.array[0, 0, 0] == 0 and field.array[8, 8, 8] == 4
    assert not engine.ready and "device lost" in engine.not_ready_reason()
    with pytest.raises(NotReady, match="device lost"):  # the read waiting for a version too
        waiting.result(timeout=10)
    with pytest.raises(NotReady, match="device lost"):  # and what comes later, at once
        engine.submit(OnDevice(lambda: None)).result(timeout=10)
    engine.stop()


def test_a_step_that_raises_fails_its_commands_and_the_engine_goes_on(engine, monkeypatch, caplog):
    """Not a command's error: the step's (a bug, a kernel that fails to build on first use)."""
    world_id = create(engine)
    world = engine.worlds[world_id]
    begin_recompute = world.begin_recompute
    monkeypatch.setattr(world, "begin_recompute", lambda piece_s=None: (_ for _ in ()).throw(RuntimeError("a bug\nin detail")))
    batch = edits(engine, world_id, [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2], "colour": 1}])
    read, describe = engine.submit(Read(world_id, "distance")), engine.submit(Describe(world_id))
    engine.step()
    assert batch.result(timeout=10) == 1  # applied and acknowledged before the recompute raised
    for future in (read, describe):
        with pytest.raises(SdfServerError, match="internal error in an engine step: RuntimeError: a bug$") as caught:
            future.result(timeout=10)
        assert type(caught.value) is SdfServerError and caught.value.code == "internal_error"  # a 500
    assert caplog.text.count("Traceback") == 1
    monkeypatch.setattr(world, "begin_recompute", begin_recompute)
    later = edits(engine, world_id, [{"op": "voxels", "voxels": [[9, 9, 9, 3]]}])
    read = engine.submit(Read(world_id, "distance"))
    engine.step()
    assert later.result(timeout=10) == 2 and read.result(timeout=10).array[9, 9, 9] == 0


def test_a_failed_warm_up_is_why_the_engine_cannot_serve(gpu, monkeypatch):
    engine = Engine(gpu)

    def fail():
        raise RuntimeError("kernel build failed\nthe whole build log")

    monkeypatch.setattr(engine, "_warm_up", fail)
    engine.start(warm_up=True)
    try:
        reason = engine.wait_started(timeout_s=60)
        assert reason == f"the engine could not start on {gpu.device_name}: RuntimeError: kernel build failed"
        assert not engine.ready and engine.not_ready_reason() == reason
        with pytest.raises(NotReady, match="kernel build failed"):
            engine.submit(Describe(None)).result(timeout=10)
    finally:
        engine.stop()


def test_a_dead_engine_thread_fails_everything_and_says_so(gpu, monkeypatch):
    """A bug outside any step: whoever started the engine hears of it (the server exits)."""
    engine = Engine(gpu)
    died = []
    gate = threading.Event()

    def broken_wait_timeout():
        gate.wait(30)
        raise RuntimeError("a bug in the loop")

    monkeypatch.setattr(engine, "_wait_timeout", broken_wait_timeout)
    engine.start(warm_up=False, on_death=died.append)
    assert engine.wait_started(timeout_s=60) is None
    queued = engine.submit(Describe(None))
    gate.set()
    with pytest.raises(NotReady, match="the engine thread died: RuntimeError: a bug in the loop"):
        queued.result(timeout=30)
    assert died == ["the engine thread died: RuntimeError: a bug in the loop"] and not engine.ready
    with pytest.raises(NotReady, match="the engine thread died"):
        engine.submit(Describe(None)).result(timeout=10)
    engine.stop()


def test_engine_and_world_do_not_import_the_web_stack():
    code = ("import sys, sdfserver.engine, sdfserver.world; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('fastapi', 'starlette', 'pydantic')); "
            "print(bad); raise SystemExit(1 if bad else 0)")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          env={"PYTHONPATH": checkout_env()["PYTHONPATH"], "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stdout + done.stderr
    # the engine process as a whole (it reads Settings, a pydantic-settings model) serves no HTTP
    code = ("import sys, sdfserver.engine.proc, sdfserver.engine.service; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('fastapi', 'starlette', 'uvicorn')); "
            "print(bad); raise SystemExit(1 if bad else 0)")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          env={"PYTHONPATH": checkout_env()["PYTHONPATH"], "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stdout + done.stderr


def test_new_world_ids_are_hex_and_never_look_like_options():
    from sdfserver.engine.core import new_world_id

    ids = {new_world_id() for _ in range(2000)}
    assert len(ids) == 2000
    assert all(len(i) == 12 and set(i) <= set("0123456789abcdef") for i in ids)


def test_a_slow_step_is_logged_with_its_phases_and_cpu_use(gpu, caplog, monkeypatch):
    from sdfserver.engine import stepclock

    now = [0.0]
    monkeypatch.setattr(stepclock, "slow_steps", stepclock.SlowStepLog(interval_s=10, clock=lambda: now[0]))
    engine = Engine(gpu, EngineLimits(slow_step_ms=0.0))  # every step counts as slow
    try:
        world_id = create(engine)
        edits(engine, world_id, [{"op": "sphere", "center": [8, 8, 8], "radius": 3, "colour": 1}])
        now[0] += 10  # past the line of the step that made the world
        with caplog.at_level("WARNING", logger="sdfserver.engine"):
            caplog.clear()
            report = engine.step()
            lines = [r.getMessage() for r in caplog.records if "slow engine step" in r.getMessage()]
            assert len(lines) == 1
            line = lines[0]
            assert report.applied_batches == 1 and line.endswith(", 1 batches")
            assert report.cpu_ms > 0 and "of apply" in line
            # the line carries the step's own figures
            assert f"{report.cpu_ms:.1f} ms of it on a CPU ({report.user_ms:.1f} user, {report.system_ms:.1f} " \
                   f"system; {report.page_faults} page faults, {report.preempted} preemptions)" in line

            # at most a line every interval: the steps left out are counted on the next line
            for moved in (5, 0, 5):  # two steps within the interval, one after it
                now[0] += moved
                edits(engine, world_id, [{"op": "sphere", "center": [8, 8, 8], "radius": 2, "colour": 0}])
                engine.step()
            lines = [r.getMessage() for r in caplog.records if "slow engine step" in r.getMessage()]
            assert len(lines) == 2 and lines[1].startswith("slow engine step: ")
            assert ", 1 batches; 2 more slow steps (the slowest " in lines[1]
    finally:
        engine.stop()


def test_the_engine_sequences_the_collaborators_it_is_handed(gpu):
    from sdfserver.engine.core import EngineParts
    from sdfserver.engine.metrics import EngineMetrics

    published = []
    metrics, limits = EngineMetrics(), EngineLimits()
    parts = EngineParts.build(gpu, limits, None, metrics, lambda: False)
    parts.subscriptions.publish = published.append  # the step's publish phase, observed
    engine = Engine(gpu, limits, metrics=metrics, parts=parts)
    created = engine.submit(CreateWorld(WorldConfig(size=(8, 8, 8), chunk_size=8, max_distance=4)))
    engine.step()
    world_id = created.result()["id"]
    assert parts.table.worlds is engine.worlds and world_id in parts.table.worlds
    edits(engine, world_id, [{"op": "box", "min": [1, 1, 1], "max": [2, 2, 2], "colour": 3}])
    engine.step()
    assert [list(recomputed) for recomputed in published] == [[], [world_id]]
    engine.stop()
