"""The data directory with real files: recovery, snapshots and trimming, the catalog,
group commit, and the failed state after a write or sync error."""

import contextlib
import os
import threading

import numpy as np
import pytest

from sdfserver.errors import CorruptData, InvalidInput, NotFound, WritesDisabled
from sdfserver.storage import Storage, decode_batch
from sdfserver.storage import committer, wal
from sdfserver.storage.framing import encode_record
from sdfserver.storage.wal import segment_base, segment_name

CONFIG = {"size": [8, 8, 16], "chunk_size": 8, "max_distance": 255, "algorithm": "exact"}


@pytest.fixture
def storage(tmp_path):
    s = Storage(tmp_path / "data")
    yield s
    s.close()


def reopen(storage, world_id="w"):
    storage.close()
    fresh = Storage(storage.data_dir)
    return fresh, *fresh.open_world(world_id)


def random_voxels(rng):
    return rng.integers(0, 256, size=(16, 8, 8), dtype=np.uint8)


def test_appended_batches_survive_a_restart(storage):
    rng = np.random.default_rng()
    store = storage.create_world("w", {"config": CONFIG, "owner": "k1"})
    batches = [[{"op": "voxels", "voxels": rng.integers(0, 8, size=(5, 4), dtype=np.uint16)},
                {"op": "sphere", "center": [1.5, 2, 3], "radius": 2.0, "colour": int(c)}]
               for c in rng.integers(1, 256, size=7)]
    for v, batch in enumerate(batches, start=1):
        store.append(v, batch).result()
    store.close()
    storage, store, rec = reopen(storage)
    try:
        assert rec.snapshot_version == 0 and rec.voxels is None and rec.last_version == 7
        assert [v for v, _ in rec.records] == list(range(1, 8))
        for (_, payload), batch in zip(rec.records, batches):
            got = decode_batch(payload)
            np.testing.assert_array_equal(got[0]["voxels"], batch[0]["voxels"])
            assert got[0]["voxels"].dtype == np.uint16 and got[1] == batch[1]
        assert storage.read_meta("w")["owner"] == "k1"
        store.append(8, b"next").result()
    finally:
        storage.close()


def test_torn_tail_is_truncated_and_appends_continue(storage):
    store = storage.create_world("w", {"config": CONFIG})
    for v in (1, 2, 3):
        store.append(v, b"batch %d" % v).result()
    store.close()
    path = storage.worlds_dir / "w" / segment_name(0, epoch=1)  # created at epoch 1
    size = path.stat().st_size
    with open(path, "ab") as f:
        f.write(encode_record(4, b"never acknowledged")[:-3])
    storage, store, rec = reopen(storage)
    assert [v for v, _ in rec.records] == [1, 2, 3] and "torn" in rec.torn
    assert path.stat().st_size == size
    store.append(4, b"batch 4").result()
    store.close()
    storage, store, rec = reopen(storage)
    assert rec.records[-1] == (4, b"batch 4") and rec.torn == ""
    store.close()
    storage.close()


def test_corruption_in_the_middle_refuses_the_world(storage):
    store = storage.create_world("w", {"config": CONFIG})
    for v in range(1, 6):
        store.append(v, b"payload %d" % v).result()
    store.close()
    path = storage.worlds_dir / "w" / segment_name(0, epoch=1)  # created at epoch 1
    data = bytearray(path.read_bytes())
    data[40] ^= 0x10  # inside the second record
    path.write_bytes(bytes(data))
    storage.close()
    fresh = Storage(storage.data_dir)
    try:
        with pytest.raises(CorruptData) as info:
            fresh.open_world("w")
        assert str(path) in str(info.value) and info.value.offset is not None
        assert path.read_bytes() == bytes(data)  # nothing truncated or rewritten
    finally:
        fresh.close()


def test_snapshot_trims_the_log_and_recovery_replays_the_rest(tmp_path):
    rng = np.random.default_rng()
    storage = Storage(tmp_path / "data", segment_limit=64)  # a new segment every few records
    store = storage.create_world("w", {"config": CONFIG})
    directory = storage.worlds_dir / "w"
    for v in range(1, 11):
        store.append(v, b"%d" % v).result()
    bases = sorted(segment_base(p) for p in directory.glob("wal-*"))
    assert len(bases) >= 3 and bases[0] == 0  # appends rotated the log as it grew
    voxels = random_voxels(rng)
    store.snapshot(7, CONFIG, voxels)  # a lagging snapshot: 8..10 stay in the log
    kept = sorted(segment_base(p) for p in directory.glob("wal-*"))
    assert kept[0] <= 7 and (len(kept) == 1 or kept[1] > 7)  # only segments wholly <= 7 went
    assert kept == [b for b in bases if b >= kept[0]]
    for v in range(11, 14):
        store.append(v, b"%d" % v).result()
    store.snapshot(13, CONFIG, voxels)
    kept = sorted(segment_base(p) for p in directory.glob("wal-*"))
    assert kept[0] <= 13 and all(b > 13 for b in kept[1:])
    assert [p.name for p in directory.glob("snap-*")] == ["snap-00000000000000000013.sdfsnap"]
    store.append(14, b"14").result()
    store.close()
    storage.close()
    storage = Storage(tmp_path / "data", segment_limit=64)
    store, rec = storage.open_world("w")
    assert rec.snapshot_version == 13 and rec.records == [(14, b"14")]
    np.testing.assert_array_equal(rec.voxels, voxels)
    store.close()
    storage.close()


def test_a_snapshot_leaves_the_open_segment_alone(storage):
    """A checkpoint never rotates the log: the engine's appends do not wait for it."""
    rng = np.random.default_rng()
    store = storage.create_world("w", {"config": CONFIG})
    for v in range(1, 11):
        store.append(v, b"%d" % v).result()
    directory = storage.worlds_dir / "w"
    voxels = random_voxels(rng)
    store.snapshot(10, CONFIG, voxels)
    assert [p.name for p in directory.glob("wal-*")] == [segment_name(0, epoch=1)]
    store.append(11, b"11").result()
    store.close()
    storage, store, rec = reopen(storage)
    assert (rec.snapshot_version, rec.records, rec.last_version) == (10, [(11, b"11")], 11)
    np.testing.assert_array_equal(rec.voxels, voxels)
    store.close()
    storage.close()


def test_replacing_snapshot_starts_a_new_log(storage):
    rng = np.random.default_rng()
    store = storage.create_world("w", {"config": CONFIG})
    store.append(1, b"1").result()
    voxels = random_voxels(rng)
    store.snapshot(2, CONFIG, voxels)  # an upload: version 2 is the whole world
    store.append(3, b"3").result()
    store.close()
    storage, store, rec = reopen(storage)
    assert (rec.snapshot_version, rec.records, rec.last_version) == (2, [(3, b"3")], 3)
    np.testing.assert_array_equal(rec.voxels, voxels)
    store.close()
    storage.close()


def test_a_gap_between_snapshot_and_log_is_refused(tmp_path):
    storage = Storage(tmp_path / "data", segment_limit=1)  # one record per segment
    store = storage.create_world("w", {"config": CONFIG})
    for v in range(1, 4):
        store.append(v, b"x").result()
    store.snapshot(3, CONFIG, np.zeros((16, 8, 8), np.uint8))
    store.close()
    for snap in (storage.worlds_dir / "w").glob("snap-*"):
        snap.unlink()  # the log before version 3 is gone with it
    storage.close()
    fresh = Storage(storage.data_dir)
    try:
        with pytest.raises(CorruptData, match="missing"):
            fresh.open_world("w")
    finally:
        fresh.close()


def test_catalog(storage):
    assert storage.world_ids() == []
    for name in ("b", "a"):
        storage.create_world(name, {"config": CONFIG, "owner": name}).close()
    with pytest.raises(InvalidInput):
        storage.create_world("a", {"config": CONFIG})
    for bad in ("../escape", ".hidden", "a/b", ""):
        with pytest.raises(InvalidInput):
            storage.create_world(bad, {"config": CONFIG})
    storage.create_world("_x-Y.1", {"config": CONFIG}).close()  # what secrets.token_urlsafe makes
    storage.delete_world("_x-Y.1")
    (storage.worlds_dir / ".new-c-1234").mkdir()  # a creation a crash interrupted
    storage.close()
    storage = Storage(storage.data_dir)
    assert storage.world_ids() == ["a", "b"]
    assert not (storage.worlds_dir / ".new-c-1234").exists()
    assert storage.catalog()["b"]["owner"] == "b"
    storage.delete_world("a")
    assert storage.world_ids() == ["b"]
    with pytest.raises(NotFound):
        storage.open_world("a")
    storage.close()


def test_group_commit_shares_syncs(storage, monkeypatch):
    real = os.fdatasync
    calls = []

    def slow_sync(fd):
        calls.append(fd)
        threading.Event().wait(0.005)
        real(fd)

    monkeypatch.setattr(os, "fdatasync", slow_sync)
    store = storage.create_world("w", {"config": CONFIG})
    lock, next_version = threading.Lock(), iter(range(1, 10 ** 6))

    def client():
        for _ in range(20):
            with lock:
                future = store.append(next(next_version), b"batch")
            future.result()

    threads = [threading.Thread(target=client) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert storage.committer.records == 160
    assert len(calls) < 80, f"{len(calls)} syncs for 160 records"
    store.close()


def test_hand_over_returns_once_an_idle_committer_has_taken_every_world(storage, monkeypatch):
    monkeypatch.setattr(committer, "HANDOVER_TIMEOUT_S", 30.0)  # a slow CI machine still hands over
    stores = [storage.create_world(name, {"config": CONFIG}) for name in "abc"]
    for version in range(1, 11):
        durable = [store.append_many(version, [b"batch"], wake=False) for store in stores]
        storage.committer.hand_over()
        # Taken already, all three in one round: the syncs do not wait for this thread to
        # give up the GIL.
        assert storage.committer.waiting == 0
        for future in durable:
            future.result()  # the committer is idle again for the next
    for store in stores:
        store.close()


def test_a_round_of_syncs_completes_its_futures_inside_one_completing_block(storage, monkeypatch):
    """The engine process sends the acknowledgements a round releases together, as that block
    ends (EngineTransport.holding): every future of the round completes inside one block."""
    monkeypatch.setattr(committer, "HANDOVER_TIMEOUT_S", 30.0)
    blocks, inside = [], threading.local()

    @contextlib.contextmanager
    def completing():
        inside.block = len(blocks)
        blocks.append("open")
        try:
            yield
        finally:
            blocks[inside.block] = "closed"
            inside.block = None

    storage.committer.completing = completing
    stores = [storage.create_world(name, {"config": CONFIG}) for name in "abc"]
    seen = []
    durable = [store.append_many(1, [b"batch"], wake=False) for store in stores]
    for future in durable:
        future.add_done_callback(lambda _: seen.append(getattr(inside, "block", None)))
    storage.committer.hand_over()
    for future in durable:
        future.result()
    assert seen == [0, 0, 0] and blocks == ["closed"]
    for store in stores:
        store.close()


@pytest.mark.parametrize("inline", [False, True], ids=["committer", "inline"])
def test_a_failed_sync_is_never_retried_and_acknowledged(tmp_path, monkeypatch, inline):
    storage = Storage(tmp_path / "data", sync_inline=inline)
    store = storage.create_world("w", {"config": CONFIG})
    store.append(1, b"fine").result()

    def broken(fd):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "fdatasync", broken)
    with pytest.raises(WritesDisabled, match="fdatasync of .*wal-.*Input/output error"):
        store.append(2, b"lost").result()
    monkeypatch.undo()
    with pytest.raises(WritesDisabled, match="writes are disabled"):
        store.append(3, b"refused")
    with pytest.raises(WritesDisabled):  # nor a new world: it could not take an edit either
        storage.create_world("v", {"config": CONFIG})
    assert not (storage.worlds_dir / "v").exists()
    store.close()
    storage.close()


def test_inline_sync_completes_the_append_itself(tmp_path, monkeypatch):
    storage = Storage(tmp_path / "data", sync_inline=True)
    store = storage.create_world("w", {"config": CONFIG})
    real, synced = os.fdatasync, []

    def counting(fd):
        synced.append((threading.get_ident(), fd))
        real(fd)

    monkeypatch.setattr(os, "fdatasync", counting)
    futures = [store.append_many(1, [b"one", b"two"]), store.append(3, b"three")]
    assert all(f.done() and f.exception() is None for f in futures)  # durable on return
    assert synced == [(threading.get_ident(), store.log._fd)] * 2  # one sync a write, on this thread
    monkeypatch.undo()
    store.close()
    storage, store, rec = reopen(storage)
    assert rec.records == [(1, b"one"), (2, b"two"), (3, b"three")]
    store.close()
    storage.close()


def test_a_failed_write_leaves_no_partial_record(storage, monkeypatch):
    store = storage.create_world("w", {"config": CONFIG})
    store.append(1, b"fine").result()
    path = store.log.segment
    size = path.stat().st_size
    real_write = os.write

    def short_then_fail(fd, data):
        if fd == store.log._fd:
            real_write(fd, bytes(data)[:5])
            raise OSError(28, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", short_then_fail)
    with pytest.raises(WritesDisabled, match="No space left"):
        store.append(2, b"does not fit")
    monkeypatch.undo()
    assert path.stat().st_size == size
    store.close()
    storage, store, rec = reopen(storage)
    assert rec.records == [(1, b"fine")] and rec.torn == ""
    store.close()
    storage.close()
