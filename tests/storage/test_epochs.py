"""Epochs and fencing with real files: a world taken over by another holder (a move, a restarted
engine) refuses to acknowledge what its old holder writes afterwards, and recovery ignores it."""

import numpy as np
import pytest

from sdfserver.errors import NotFound, WorldFenced
from sdfserver.storage import Storage, batch_parts, decode_batch
from sdfserver.storage.framing import encode_record
from sdfserver.storage.recovery import recover_world
from sdfserver.storage.wal import segment_epoch

CONFIG = {"size": [8, 8, 16], "chunk_size": 8, "max_distance": 255, "algorithm": "exact"}


@pytest.fixture
def two(tmp_path):
    """Two engines' data directories on one file system."""
    a, b = Storage(tmp_path / "engine-0"), Storage(tmp_path / "engine-1")
    yield a, b
    a.close()
    b.close()


def written(storage: Storage, world_id: str = "w") -> list[tuple[int, bytes]]:
    """What a start would recover of the world (read only: a second Storage may not open a data
    directory that one holds, as the engine's lock ensures)."""
    return recover_world(storage.worlds_dir / world_id).records


def fill(store, versions, tag=b"a"):
    for v in versions:
        store.append(v, tag + b"%d" % v).result()


def test_a_world_handed_over_continues_under_a_new_epoch(two):
    a, b = two
    store = a.create_world("w", {"config": CONFIG})
    assert store.epoch == 1
    fill(store, range(1, 6))
    a.hand_over("w", store, b.data_dir)
    assert a.world_ids() == [] and b.world_ids() == ["w"]
    moved, recovered = b.open_world("w")
    assert moved.epoch == 2 and [v for v, _ in recovered.records] == [1, 2, 3, 4, 5]
    fill(moved, range(6, 9), b"b")
    moved.close()
    assert [p for _, p in written(b)] == [b"a1", b"a2", b"a3", b"a4", b"a5", b"b6", b"b7", b"b8"]


def test_the_old_holder_of_a_world_taken_over_cannot_acknowledge(two):
    a, b = two
    stale = a.create_world("w", {"config": CONFIG})
    fill(stale, range(1, 4))
    b.take_over("w", a.data_dir)  # its holder did not answer: fetched, and fenced by the epoch
    holder, _ = b.open_world("w")
    with pytest.raises(WorldFenced):
        stale.append(4, b"stale 4").result()
    fill(holder, range(4, 6), b"b")
    holder.close()
    assert [p for _, p in written(b)] == [b"a1", b"a2", b"a3", b"b4", b"b5"]
    with pytest.raises(WorldFenced):
        stale.snapshot(3, CONFIG, np.zeros((16, 8, 8), np.uint8))
    with pytest.raises(NotFound):
        b.take_over("gone", a.data_dir)


def test_a_restarted_holder_fences_the_one_still_running_in_the_same_directory(tmp_path):
    """What a zombie engine (its replacement already started) writes is ignored at recovery."""
    old, new = Storage(tmp_path / "data"), Storage(tmp_path / "data")
    try:
        stale = old.create_world("w", {"config": CONFIG})
        fill(stale, range(1, 4))
        holder, recovered = new.open_world("w")
        assert holder.epoch == 2 and recovered.last_version == 3
        for v in (4, 5):  # the zombie goes on writing into its own segment
            with pytest.raises(WorldFenced):
                stale.append(v, b"stale %d" % v).result()
        fill(holder, range(4, 7), b"new")
        holder.close()
        check = Storage(tmp_path / "data")
        store, recovered = check.open_world("w")
        assert [p for _, p in recovered.records] == [b"a1", b"a2", b"a3", b"new4", b"new5", b"new6"]
        assert recovered.fenced_records == 2 and store.epoch == 3
        store.close()
        check.close()
    finally:
        old.close()
        new.close()


def test_a_write_appended_before_the_new_holder_read_the_log_is_kept_not_acknowledged(tmp_path):
    old, new = Storage(tmp_path / "data"), Storage(tmp_path / "data")
    try:
        stale = old.create_world("w", {"config": CONFIG})
        fill(stale, range(1, 3))
        pending = stale.log.append_many(3, [b"in flight"], wake=False)  # written, not yet synced
        holder, recovered = new.open_world("w")
        old.committer.hand_over()
        with pytest.raises(WorldFenced):  # its holder changed before its sync: not acknowledged
            pending.result(timeout=10)
        assert recovered.records[-1] == (3, b"in flight")  # but the new holder has it: a retry
        holder.close()  # that carries its Idempotency-Key is found there, not applied twice
    finally:
        old.close()
        new.close()


def test_an_older_epochs_torn_tail_before_a_newer_epoch_is_not_damage(tmp_path):
    storage = Storage(tmp_path / "data")
    store = storage.create_world("w", {"config": CONFIG})
    fill(store, range(1, 3))
    store.close()
    storage.close()
    first = next((tmp_path / "data" / "worlds" / "w").glob("wal-*"))
    with open(first, "ab") as f:  # a crash in the middle of an append
        f.write(encode_record(3, b"torn")[:-2])
    storage = Storage(tmp_path / "data")
    store, recovered = storage.open_world("w")
    assert "torn" in recovered.torn and [v for v, _ in recovered.records] == [1, 2]
    fill(store, range(3, 5), b"n")
    store.close()
    storage.close()
    assert [p for _, p in written(storage)] == [b"a1", b"a2", b"n3", b"n4"]
    segments = sorted((tmp_path / "data" / "worlds" / "w").glob("wal-*"), key=segment_epoch)
    assert [segment_epoch(s) for s in segments] == [1, 2]


def test_batch_ids_survive_a_move(two):
    a, b = two
    store = a.create_world("w", {"config": CONFIG})
    from sdfserver.storage.codec import encode_batch
    store.append(1, encode_batch([{"op": "box", "min": [0, 0, 0], "max": [1, 1, 1], "colour": 3}], "key-1")).result()
    a.hand_over("w", store, b.data_dir)
    moved, recovered = b.open_world("w")
    moved.close()
    assert batch_parts(decode_batch(recovered.records[0][1]))[1] == "key-1"
