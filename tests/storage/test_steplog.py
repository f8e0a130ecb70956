"""The step log (storage/steplog.py): a step's batches of every world are durable with one sync,
and what a world's own log loses in a crash (writes that were never synced: a torn tail, a hole
with later records after it) comes back from the step log at the next start, or when another
engine takes the world over; a checkpoint syncs the world logs and drops the old segment."""

from __future__ import annotations

import os

import numpy as np
import pytest

from sdfserver.errors import CorruptData
from sdfserver.storage import Storage, steplog
from sdfserver.storage.framing import SEGMENT_HEADER
from sdfserver.storage.journal import StorageJournal
from sdfserver.storage.recovery import recover_world
from sdfserver.storage.steplog import STEP_DIR, step_segments

CONFIG = {"size": [8, 8, 8]}


def batch(world: int, version: int) -> bytes:
    return f"world {world} batch {version}".encode() * 3


def step(journal: StorageJournal, ids: list[str], versions: list[int], count: int = 2) -> None:
    """``count`` batches for each world in one step, acknowledged (durable) before returning."""
    futures = []
    for w, world_id in enumerate(ids):
        futures.append(journal.record_batches(world_id, versions[w] + 1,
                                              [batch(w, versions[w] + 1 + i) for i in range(count)]))
        versions[w] += count
    journal.start_syncs()
    for future in futures:
        future.result(timeout=10)


def segment_of(journal: StorageJournal, world_id: str):
    return journal.stores[world_id].log.segment


def crash(storage: Storage) -> None:
    """Stop without closing the logs (no sync, no checkpoint): what a killed engine leaves."""
    storage.committer.close()


def wait_for_checkpoints(storage: Storage) -> None:
    storage.steps._checkpoints.submit(lambda: None).result(timeout=10)


def recovered(data_dir, world_id: str) -> list[tuple[int, bytes]]:
    return recover_world(data_dir / "worlds" / world_id).records


def test_lost_world_log_writes_come_back_from_the_step_log(tmp_path, monkeypatch):
    data = tmp_path / "data"
    storage = Storage(data)
    journal = StorageJournal(storage)
    ids = ["torn", "holed", "kept"]
    for world_id in ids:
        journal.record_create(world_id, CONFIG)
    versions = [0, 0, 0]
    step(journal, ids, versions)
    assert all(os.path.getsize(segment_of(journal, w)) == SEGMENT_HEADER.size for w in ids)  # held
    for world_id in ids:  # as a checkpoint does: written and synced
        journal.stores[world_id].log.sync_written()
    synced = {w: os.path.getsize(segment_of(journal, w)) for w in ids}
    for _ in range(3):
        step(journal, ids, versions)
    with monkeypatch.context() as unsynced:  # a checkpoint's writes whose syncs never held
        unsynced.setattr(os, "fdatasync", lambda fd: None)
        for world_id in ids:
            journal.stores[world_id].log.sync_written()
    assert len(os.listdir(data / STEP_DIR)) == 1
    torn, holed = segment_of(journal, "torn"), segment_of(journal, "holed")
    crash(storage)
    # what the page cache had not written: the tail of one log, a hole in the middle of another
    os.truncate(torn, synced["torn"] + 5)
    with open(holed, "r+b") as f:
        f.seek(synced["holed"] + 3)
        f.write(b"\0" * 40)
    with pytest.raises(CorruptData):  # without the step log the hole could not be read past
        recover_world(data / "worlds" / "holed")

    synced = []
    real_fsync_file = steplog.fsync_file
    monkeypatch.setattr(steplog, "fsync_file", lambda path: synced.append(path) or real_fsync_file(path))
    kept = segment_of(journal, "kept")
    Storage(data).close()  # the next start replays the step log into the world logs
    assert synced == [kept]  # whole, but unsynced since its batches: synced before the step log goes
    for w, world_id in enumerate(ids):
        assert recovered(data, world_id) == [(v, batch(w, v)) for v in range(1, 9)]
    assert not step_segments(data / STEP_DIR)


def test_another_engine_taking_a_world_gets_what_its_holder_acknowledged(tmp_path):
    source, target = tmp_path / "a", tmp_path / "b"
    storage = Storage(source)
    journal = StorageJournal(storage)
    journal.record_create("w", CONFIG)
    journal.record_create("stays", CONFIG)
    versions = [0, 0]
    step(journal, ["w", "stays"], versions)
    synced = os.path.getsize(segment_of(journal, "w"))
    step(journal, ["w", "stays"], versions)
    crash(storage)
    os.truncate(segment_of(journal, "w"), synced)

    other = Storage(target)
    other.take_over("w", source)
    store, found = other.open_world("w")
    assert found.records == [(v, batch(0, v)) for v in range(1, 5)]
    other.close()
    # the old holder's next start finds the world gone and replays only what is still its own
    again = Storage(source)
    assert recovered(source, "stays") == [(v, batch(1, v)) for v in range(1, 5)]
    again.close()


def test_a_checkpoint_syncs_the_world_logs_and_drops_the_old_segment(tmp_path):
    data = tmp_path / "data"
    storage = Storage(data)
    journal = StorageJournal(storage)
    journal.record_create("w", CONFIG)
    storage.steps.segment_limit = 1  # each record in a segment of its own
    versions = [0]
    step(journal, ["w"], versions)  # to the second segment (the first ends before its first record)
    assert journal.stores["w"].log.unsynced
    step(journal, ["w"], versions)  # to the third: the second is checkpointed
    wait_for_checkpoints(storage)
    assert [p.name for p in step_segments(data / STEP_DIR)] == [f"steps-{storage.epoch}-3.log"]
    storage.close()
    assert recovered(data, "w") == [(v, batch(0, v)) for v in range(1, 5)]


def test_versions_neither_log_holds_are_refused(tmp_path):
    data = tmp_path / "data"
    storage = Storage(data)
    journal = StorageJournal(storage)
    journal.record_create("w", CONFIG)
    synced_end = os.path.getsize(segment_of(journal, "w"))
    storage.steps.segment_limit = 1
    versions = [0]
    step(journal, ["w"], versions)
    step(journal, ["w"], versions)  # the second segment, with versions 1 and 2, is checkpointed and deleted
    wait_for_checkpoints(storage)
    crash(storage)
    os.truncate(segment_of(journal, "w"), synced_end)  # as if the checkpoint's sync had not held
    with pytest.raises(CorruptData, match="versions in between are lost"):
        Storage(data)


def test_held_records_reach_the_world_log_in_order_across_rotations_and_a_snapshot(tmp_path):
    data = tmp_path / "data"
    storage = Storage(data, segment_limit=200)  # a world-log segment holds a write or two
    journal = StorageJournal(storage)
    journal.record_create("w", CONFIG)
    store = journal.stores["w"]
    versions = [0]
    for round_ in range(6):
        before = (store.log.segment, os.path.getsize(store.log.segment))
        step(journal, ["w"], versions, count=3)
        assert (store.log.segment, os.path.getsize(store.log.segment)) == before  # held, not written
        if round_ % 2:  # a checkpoint's writes: held records go out, to a new segment once one is full
            store.log.sync_written()
            assert os.path.getsize(store.log.segment) > SEGMENT_HEADER.size
        if round_ == 3:  # a snapshot of a version whose records are partly still held
            store.snapshot(versions[0] - 1, CONFIG, np.zeros((8, 8, 8), np.uint8))
    assert len(store.log.segments()) > 1
    storage.close()
    found = recover_world(data / "worlds" / "w")
    assert found.snapshot_version == 11
    assert found.records == [(v, batch(0, v)) for v in range(12, 19)]


def test_a_holder_taken_over_writes_nothing_it_held(tmp_path):
    source, target = tmp_path / "a", tmp_path / "b"
    storage = Storage(source)
    journal = StorageJournal(storage)
    journal.record_create("w", CONFIG)
    versions = [0]
    step(journal, ["w"], versions)  # acknowledged: in the step log, held by the world's log
    held = journal.stores["w"].log
    other = Storage(target)
    other.take_over("w", source)  # the holder does not answer: its step log is replayed there
    store, found = other.open_world("w")
    assert found.records == [(v, batch(0, v)) for v in (1, 2)]
    held.sync_written()  # the old holder's checkpoint comes late: fenced, it writes nothing
    store.close()
    other.close()
    assert recovered(target, "w") == [(v, batch(0, v)) for v in (1, 2)]
    storage.close()
