"""The storage journal inside the engine, without HTTP: a batch is acknowledged only once its
log record is durable, a failed sync fails it and refuses every later batch, snapshots are taken
after recomputes, and restore_worlds rebuilds the same worlds in a fresh engine."""

from __future__ import annotations

import logging
import os
import shutil
import threading

import numpy as np
import pytest

from sdfserver.edits import parse_edits
from sdfserver.engine import Engine, core
from sdfserver.engine.commands import ApplyEdits, CreateWorld, Describe, Read
from sdfserver.engine.restore import restore_worlds
from sdfserver.errors import WritesDisabled
from sdfserver.storage import Storage
from sdfserver.storage.journal import StorageJournal
from sdfserver.storage.snapshot import decode_snapshot
from sdfserver.world import World, WorldConfig

from durable_server import apply_reference, random_batch
from references import oracle_distance


@pytest.fixture
def journal(tmp_path):
    journal = StorageJournal(Storage(tmp_path / "data"), snapshot_every_batches=3)
    yield journal
    journal.close()


def edits(engine, world_id, raw):
    return engine.submit(ApplyEdits(world_id, parse_edits(raw), raw))


def test_acknowledged_only_when_durable(gpu, journal, monkeypatch):
    engine = Engine(gpu, journal=journal)
    created = engine.submit(CreateWorld(WorldConfig(size=(16, 16, 16), chunk_size=8, max_distance=6),
                                        owner="alice"))
    engine.step()
    world_id = created.result()["id"]
    assert created.result()["owner"] == "alice"
    gate, real = threading.Event(), os.fdatasync
    monkeypatch.setattr(os, "fdatasync", lambda fd: (gate.wait(10), real(fd)))
    first = edits(engine, world_id, [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2], "colour": 3}])
    engine.step()
    assert not first.done(), "acknowledged before the log record was durable"
    gate.set()
    assert first.result(timeout=10) == 1

    def broken(fd):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "fdatasync", broken)
    failing = edits(engine, world_id, [{"op": "box", "min": [4, 4, 4], "max": [5, 5, 5], "colour": 1}])
    engine.step()
    with pytest.raises(WritesDisabled):
        failing.result(timeout=10)
    refused = edits(engine, world_id, [{"op": "box", "min": [6, 6, 6], "max": [7, 7, 7], "colour": 1}])
    engine.step()
    with pytest.raises(WritesDisabled, match="writes are disabled"):
        refused.result(timeout=10)
    engine.stop()


def test_a_lone_batch_is_acknowledged_before_its_step_recomputes(gpu, journal, monkeypatch):
    """With nothing else queued the step waits for the acknowledgement, so the log's committer
    does not wait for the GIL the recompute holds."""
    monkeypatch.setattr(core, "LONE_ACKNOWLEDGEMENT_WAIT_S", 30.0)  # however slow this machine's disk
    engine = Engine(gpu, journal=journal)
    created = engine.submit(CreateWorld(WorldConfig(size=(16, 16, 16), chunk_size=8, max_distance=6)))
    engine.step()
    world_id = created.result()["id"]
    order, begin_recompute = [], World.begin_recompute
    monkeypatch.setattr(World, "begin_recompute", lambda self, *a: (order.append("recompute"), begin_recompute(self, *a))[1])
    for _ in range(5):
        batch = edits(engine, world_id, [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2], "colour": 3}])
        batch.add_done_callback(lambda _: order.append("acknowledged"))
        engine.step()
        batch.result(timeout=10)
    assert order == ["acknowledged", "recompute"] * 5


def test_a_command_that_comes_while_a_step_waits_for_a_slow_sync_ends_the_wait(gpu, journal, monkeypatch):
    monkeypatch.setattr(core, "LONE_ACKNOWLEDGEMENT_WAIT_S", 30.0)
    engine = Engine(gpu, journal=journal)
    created = engine.submit(CreateWorld(WorldConfig(size=(16, 16, 16), chunk_size=8, max_distance=6)))
    engine.step()
    world_id = created.result()["id"]
    gate, real = threading.Event(), os.fdatasync
    monkeypatch.setattr(os, "fdatasync", lambda fd: (gate.wait(30), real(fd)))
    batch = edits(engine, world_id, [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2], "colour": 3}])
    stepping = threading.Thread(target=engine.step)
    stepping.start()
    stepping.join(0.3)
    assert stepping.is_alive(), "the step did not wait for the acknowledgement"
    engine.submit(Describe(world_id))
    stepping.join(5)
    assert not stepping.is_alive(), "a queued command did not end the wait"
    assert not batch.done()
    gate.set()
    assert batch.result(timeout=10) == 1


def test_closing_after_the_data_directory_was_deleted_says_so_and_raises_nothing(tmp_path, caplog):
    journal = StorageJournal(Storage(tmp_path / "data"))
    durable = []
    for world_id in ("a", "b"):
        journal.record_create(world_id, {"size": [8, 8, 8], "chunk_size": 8, "max_distance": 4})
        durable.append(journal.record_batches(
            world_id, 1, [[{"op": "box", "min": [0, 0, 0], "max": [1, 1, 1], "colour": 2}]]))
    journal.start_syncs()
    for future in durable:
        future.result(timeout=10)  # acknowledged; then the directory goes, as an operator might delete it
    shutil.rmtree(tmp_path / "data")
    with caplog.at_level(logging.WARNING, logger="sdfserver.storage"):
        journal.close()
    closing = [r.getMessage() for r in caplog.records if r.getMessage().startswith("closing the log of world")]
    # the first log's sync finds the directory gone; writes are then disabled, and the other closes quietly
    assert len(closing) == 1 and "writes are disabled" in closing[0] and "data" in closing[0], closing


def test_snapshots_and_restore_into_a_fresh_engine(gpu, journal, tmp_path):
    rng = np.random.default_rng()
    engine = Engine(gpu, journal=journal)
    created = engine.submit(CreateWorld(WorldConfig(size=(16, 24, 8), chunk_size=8, max_distance=7)))
    engine.step()
    world_id = created.result()["id"]
    expected = np.zeros((8, 24, 16), np.uint8)
    at_version = {}
    for version in range(1, 12):
        batch = random_batch(rng, (16, 24, 8))
        future = edits(engine, world_id, batch)
        engine.step()
        future.result(timeout=10)
        apply_reference(expected, batch)
        at_version[version] = expected.copy()
        # Let a snapshot finish before the next batch: one still being written when the next is
        # due is skipped (by design), which on a loaded machine made the schedule vary.
        journal._wait_snapshot(world_id)
    directory = tmp_path / "data" / "worlds" / world_id
    snaps = sorted(directory.glob("snap-*"))
    assert snaps and int(snaps[-1].stem.split("-")[1]) == 9  # every 3 batches: 3, 6, 9
    # The snapshot holds the voxels of its own version, though the device copied them while
    # the engine went on (the copy is queued before any later edit).
    np.testing.assert_array_equal(decode_snapshot(snaps[-1].read_bytes()).voxels, at_version[9])
    field = engine.submit(Read(world_id, "distance"))
    engine.step()
    before = field.result().array
    engine.stop()
    journal.close()

    fresh_journal = StorageJournal(Storage(tmp_path / "data"))
    fresh = Engine(gpu, journal=fresh_journal)
    report = restore_worlds(fresh, fresh_journal.storage, fresh_journal)
    assert report.restored == [world_id] and not report.refused
    voxels, field = fresh.submit(Read(world_id, "voxels")), fresh.submit(Read(world_id, "distance"))
    fresh.step()
    assert voxels.result().version == 11
    np.testing.assert_array_equal(voxels.result().array, expected)
    np.testing.assert_array_equal(field.result().array, before)
    nxt = edits(fresh, world_id, [{"op": "box", "min": [0, 0, 0], "max": [1, 1, 1], "colour": 2}])
    fresh.step()
    assert nxt.result(timeout=10) == 12
    fresh.stop()
    fresh_journal.close()


def test_a_corrupt_world_is_refused_and_the_others_restore(gpu, journal, tmp_path):
    from sdfserver.errors import StorageError

    engine = Engine(gpu, journal=journal)
    ids = []
    for _ in range(2):
        created = engine.submit(CreateWorld(WorldConfig(size=(8, 8, 8), chunk_size=8, max_distance=4)))
        engine.step()
        ids.append(created.result()["id"])
    for v in range(2):  # below snapshot_every_batches: everything stays in the log
        for world_id in ids:
            future = edits(engine, world_id, [{"op": "box", "min": [v, 0, 0], "max": [v + 1, 1, 1], "colour": 5}])
            engine.step()
            future.result(timeout=10)
    engine.stop()
    journal.close()
    segment = next((tmp_path / "data" / "worlds" / ids[0]).glob("wal-*"))
    data = bytearray(segment.read_bytes())
    data[16 + 20] ^= 0xFF  # inside the first record; the second is intact
    segment.write_bytes(bytes(data))

    fresh_journal = StorageJournal(Storage(tmp_path / "data"))
    fresh = Engine(gpu, journal=fresh_journal)
    report = restore_worlds(fresh, fresh_journal.storage, fresh_journal)
    assert report.restored == [ids[1]] and set(report.refused) == {ids[0]}
    assert str(segment) in report.refused[ids[0]] and "offset 16" in report.refused[ids[0]]
    refused = fresh.submit(Read(ids[0], "voxels"))
    fresh.step()
    with pytest.raises(StorageError, match="not restored"):
        refused.result()
    assert segment.read_bytes() == bytes(data)  # left untouched for an operator
    fresh.stop()
    fresh_journal.close()


def test_the_api_says_writes_are_disabled(gpu, journal, monkeypatch):
    import asyncio

    import httpx

    from sdfserver.api.app import create_app
    from sdfserver.settings import Settings

    engine = Engine(gpu, journal=journal)
    app = create_app(Settings(), engine)
    app.state.journal = journal
    engine.start(warm_up=False)

    async def scenario():
        async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://t") as http:
            world = (await http.post("/v1/worlds", json={"size": [8, 8, 8], "chunk_size": 8})).json()["id"]
            box = {"edits": [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2], "colour": 3}]}
            assert (await http.post(f"/v1/worlds/{world}/edits", json=box)).json() == {"version": 1}
            assert (await http.get("/readyz")).status_code == 200

            def broken(fd):
                raise OSError(28, "No space left on device")

            monkeypatch.setattr(os, "fdatasync", broken)
            for _ in range(2):  # the failing sync, then a refusal without trying
                r = await http.post(f"/v1/worlds/{world}/edits", json=box)
                assert r.status_code == 503 and r.json()["error"]["code"] == "writes_disabled", r.text
            ready = await http.get("/readyz")
            assert ready.status_code == 503 and "No space left" in ready.json()["error"]["message"]
            assert (await http.get(f"/v1/worlds/{world}")).status_code == 200  # reads keep working

    try:
        asyncio.run(scenario())
    finally:
        engine.stop()


def test_a_steps_batches_share_one_log_write_and_restore_in_order(gpu, tmp_path):
    journal = StorageJournal(Storage(tmp_path / "data"), snapshot_every_batches=1000)
    rng = np.random.default_rng()
    engine = Engine(gpu, journal=journal)
    sizes = [(16, 8, 8), (8, 8, 16)]
    created = [engine.submit(CreateWorld(WorldConfig(size=s, chunk_size=8, max_distance=5))) for s in sizes]
    engine.step()
    ids = [c.result()["id"] for c in created]
    expected = [np.zeros(s[::-1], np.uint8) for s in sizes]
    writes = []
    real_write = os.write
    os.write = lambda fd, data: writes.append(fd) or real_write(fd, data)
    try:
        futures, batches = [], []
        for i in range(12):  # interleaved over both worlds, one invalid batch in the middle
            w = i % 2
            batch = random_batch(rng, sizes[w]) if i != 5 else [{"op": "voxels", "voxels": [[99, 0, 0, 1]]}]
            futures.append(edits(engine, ids[w], batch))
            batches.append((w, batch))
        engine.step()
    finally:
        os.write = real_write
    # one write, the step log's: the worlds' own logs take theirs at their next sync
    assert len(writes) == 1 and writes[0] == journal.storage.steps._fd
    versions = [0, 0]
    for (w, batch), future in zip(batches, futures):
        if batch[0]["op"] == "voxels" and batch[0]["voxels"] == [[99, 0, 0, 1]]:
            with pytest.raises(Exception):
                future.result(timeout=10)
            continue
        versions[w] += 1
        assert future.result(timeout=10) == versions[w]  # +1 per batch, in arrival order
        apply_reference(expected[w], batch)
    engine.stop()
    journal.close()
    fresh_journal = StorageJournal(Storage(tmp_path / "data"))
    fresh = Engine(gpu, journal=fresh_journal)
    restore_worlds(fresh, fresh_journal.storage, fresh_journal)
    reads = [fresh.submit(Read(world_id, "voxels")) for world_id in ids]
    fresh.step()
    for w, read in enumerate(reads):
        assert read.result().version == versions[w]
        np.testing.assert_array_equal(read.result().array, expected[w])
    fresh.stop()
    fresh_journal.close()


def test_a_busy_world_snapshots_at_most_once_an_interval(gpu, tmp_path):
    now = [100.0]
    journal = StorageJournal(Storage(tmp_path / "data"), snapshot_every_batches=2, snapshot_min_interval_s=10,
                             clock=lambda: now[0])
    engine = Engine(gpu, journal=journal)
    created = engine.submit(CreateWorld(WorldConfig(size=(8, 8, 8), chunk_size=8, max_distance=4)))
    engine.step()
    world_id = created.result()["id"]
    directory = tmp_path / "data" / "worlds" / world_id

    def edit_at(t: float, version: int) -> None:
        now[0] = t
        future = edits(engine, world_id, [{"op": "box", "min": [version % 8, 0, 0], "max": [8, 1, 1],
                                           "colour": version}])
        engine.step()
        assert future.result(timeout=10) == version
        journal._wait_snapshot(world_id)

    def snapshot_versions() -> list[int]:
        return sorted(int(p.stem.split("-")[1]) for p in directory.glob("snap-*"))

    for version, t in enumerate([101, 102, 103, 109.9], start=1):  # batches enough, time not
        edit_at(t, version)
    assert snapshot_versions() == []
    edit_at(110.0, 5)  # ten seconds after the world was created
    assert snapshot_versions() == [5]
    edit_at(111, 6), edit_at(112, 7), edit_at(119.9, 8)
    assert snapshot_versions() == [5]
    edit_at(120.0, 9)
    assert snapshot_versions() == [9]  # the older one is superseded and trimmed
    engine.stop()
    journal.close()


def test_restore_replays_a_long_log_in_groups(gpu, tmp_path, monkeypatch):
    import sdfserver.engine.rebuild as rebuild

    journal = StorageJournal(Storage(tmp_path / "data"), snapshot_every_batches=10_000)
    rng = np.random.default_rng()
    size = (16, 8, 24)
    engine = Engine(gpu, journal=journal)
    created = engine.submit(CreateWorld(WorldConfig(size=size, chunk_size=8, max_distance=9)))
    engine.step()
    world_id = created.result()["id"]
    expected = np.zeros(size[::-1], np.uint8)
    for _ in range(23):  # one batch a step: the log holds 23 records
        batch = random_batch(rng, size)
        future = edits(engine, world_id, batch)
        engine.step()
        future.result(timeout=10)
        apply_reference(expected, batch)
    engine.stop()
    journal.close()

    monkeypatch.setattr(rebuild, "REPLAY_GROUP", 5)  # groups of 5, 5, 5, 5, 3
    grouped = []
    real = rebuild.World.apply_plans
    monkeypatch.setattr(rebuild.World, "apply_plans", lambda self, plans: grouped.append(len(plans)) or real(self, plans))
    fresh_journal = StorageJournal(Storage(tmp_path / "data"))
    fresh = Engine(gpu, journal=fresh_journal)
    report = restore_worlds(fresh, fresh_journal.storage, fresh_journal)
    assert report.batches_replayed == 23 and grouped == [5, 5, 5, 5, 3]
    voxels, field = fresh.submit(Read(world_id, "voxels")), fresh.submit(Read(world_id, "distance"))
    fresh.step()
    assert voxels.result().version == 23
    np.testing.assert_array_equal(voxels.result().array, expected)
    assert expected.any()  # 23 random batches leave something solid: the oracle needs it
    np.testing.assert_array_equal(field.result().array, oracle_distance(expected, 9))
    fresh.stop()
    fresh_journal.close()


def test_a_batch_id_seen_before_is_answered_not_applied_again_even_after_a_restart(gpu, tmp_path):
    from sdfserver.storage.codec import encode_batch

    journal = StorageJournal(Storage(tmp_path / "data"), snapshot_every_batches=1000)
    engine = Engine(gpu, journal=journal)
    created = engine.submit(CreateWorld(WorldConfig(size=(16, 8, 8), chunk_size=8, max_distance=5)))
    engine.step()
    world_id = created.result()["id"]
    rng = np.random.default_rng()
    ids = [f"batch-{rng.integers(1 << 40)}-{i}" for i in range(3)]
    raws = [[{"op": "box", "min": [i, 0, 0], "max": [i + 2, 3, 3], "colour": 10 + i}] for i in range(3)]

    def send(target, i):
        future = target.submit(ApplyEdits(world_id, parse_edits(raws[i]), encode_batch(raws[i], ids[i]), ids[i]))
        target.step()
        return future.result(timeout=10)

    assert [send(engine, 0), send(engine, 1), send(engine, 0), send(engine, 1)] == [1, 2, 1, 2]
    read = engine.submit(Read(world_id, "voxels"))
    engine.step()
    assert read.result().version == 2
    engine.stop()
    journal.close()

    fresh_journal = StorageJournal(Storage(tmp_path / "data"))
    fresh = Engine(gpu, journal=fresh_journal)
    restore_worlds(fresh, fresh_journal.storage, fresh_journal)
    assert [send(fresh, 1), send(fresh, 2), send(fresh, 0), send(fresh, 2)] == [2, 3, 1, 3]
    read = fresh.submit(Read(world_id, "voxels"))
    fresh.step()
    expected = np.zeros((8, 8, 16), np.uint8)
    for raw in raws:
        apply_reference(expected, raw)
    assert read.result().version == 3
    np.testing.assert_array_equal(read.result().array, expected)
    fresh.stop()
    fresh_journal.close()
