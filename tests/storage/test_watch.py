"""The data directory watched: deleted or replaced under a running server, writes are disabled
and nothing more is acknowledged; failed catalog operations raise StorageError, change nothing
and leave no half-built directory; a log without its catalog entry is reported."""

import errno
import os
import shutil

import numpy as np
import pytest

from sdfserver.errors import StorageError, WritesDisabled
from sdfserver.storage import Storage
from sdfserver.storage import fsutil, store as store_module

CONFIG = {"size": [8, 8, 16], "chunk_size": 8, "max_distance": 255, "algorithm": "exact"}


@pytest.fixture(params=["committer", "inline", "no-sync"])
def storage(request, tmp_path):
    s = Storage(tmp_path / "data", sync_inline=request.param == "inline", sync=request.param != "no-sync")
    yield s
    s.close()


def test_a_deleted_data_directory_acknowledges_nothing_more(storage):
    store = storage.create_world("w", {"config": CONFIG})
    store.append(1, b"kept").result()
    shutil.rmtree(storage.data_dir)
    with pytest.raises(WritesDisabled, match="No such file or directory"):
        store.append(2, b"would be lost").result()
    with pytest.raises(WritesDisabled):
        store.append(3, b"refused")
    with pytest.raises(WritesDisabled):  # nor a new world, nor a new catalog entry
        storage.create_world("v", {"config": CONFIG})
    with pytest.raises(WritesDisabled):
        store.write_meta({"config": CONFIG})
    assert "data" in str(storage.committer.failure)
    store.close()


def test_a_replaced_data_directory_acknowledges_nothing_more(storage):
    store = storage.create_world("w", {"config": CONFIG})
    store.append(1, b"kept").result()
    os.rename(storage.data_dir, storage.data_dir.with_name("moved"))
    (storage.data_dir / "worlds").mkdir(parents=True)  # an empty one in its place
    with pytest.raises(WritesDisabled, match="replaced"):
        store.append(2, b"would be lost").result()
    store.close()


def test_a_deleted_world_directory_acknowledges_nothing_more(storage):
    store = storage.create_world("w", {"config": CONFIG})
    store.append(1, b"kept").result()
    shutil.rmtree(store.directory)
    with pytest.raises(WritesDisabled, match="deleted"):
        store.append(2, b"would be lost").result()
    store.close()


def test_a_snapshot_into_a_vanished_directory_disables_writes(storage):
    store = storage.create_world("w", {"config": CONFIG})
    store.append(1, b"kept").result()
    shutil.rmtree(storage.data_dir)
    with pytest.raises(WritesDisabled):
        store.snapshot(1, CONFIG, np.zeros((16, 8, 8), dtype=np.uint8))
    assert storage.committer.failure is not None
    store.close()


def test_a_failed_creation_leaves_nothing_behind(storage, monkeypatch):
    def full(path, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(store_module, "write_atomic", full)
    with pytest.raises(StorageError, match="No space left on device") as caught:
        storage.create_world("w", {"config": CONFIG})
    assert caught.value.code == "storage_error"
    assert list(storage.worlds_dir.iterdir()) == []  # no staging directory until a restart
    assert storage.committer.failure is None  # the logs of other worlds are fine
    monkeypatch.undo()
    storage.create_world("w", {"config": CONFIG}).close()


def test_a_failed_catalog_write_keeps_the_old_entry(storage, monkeypatch):
    store = storage.create_world("w", {"config": CONFIG, "owner": "k"})

    def read_only(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(fsutil.os, "open", read_only)
    with pytest.raises(StorageError, match="world.json.*Permission denied"):
        store.write_meta({"config": {**CONFIG, "max_distance": 9}, "owner": "k"})
    monkeypatch.undo()
    assert storage.read_meta("w")["config"]["max_distance"] == 255
    store.close()


def test_a_failed_deletion_changes_nothing(storage, monkeypatch):
    store = storage.create_world("w", {"config": CONFIG})

    def busy(self, target):
        raise OSError(errno.EBUSY, "Device or resource busy")

    monkeypatch.setattr(type(storage.worlds_dir), "rename", busy)
    with pytest.raises(StorageError, match="busy"):
        storage.delete_world("w", store)
    monkeypatch.undo()
    store.append(1, b"still logged").result()  # its log stayed open
    storage.delete_world("w", store)
    assert storage.world_ids() == []


def test_a_log_without_its_catalog_entry_is_an_orphan(storage):
    storage.create_world("w", {"config": CONFIG}).close()
    storage.create_world("v", {"config": CONFIG}).close()
    (storage.worlds_dir / "w" / "world.json").unlink()
    (storage.worlds_dir / "empty").mkdir()  # nothing to lose here
    assert storage.world_ids() == ["v"]
    assert list(storage.orphans()) == ["w"]
