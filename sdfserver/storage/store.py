"""The data directory: a catalog of worlds, each with its log and snapshots.

Layout::

    <data_dir>/
      worlds/<world id>/world.json            the catalog entry: config, owner, ... (atomic)
      worlds/<world id>/snap-<version>.sdfsnap  the latest snapshot of its voxels
      worlds/<world id>/wal-<base>-e<epoch>.log log segments, records after <base>
      worlds/<world id>/epoch                   the epoch of the engine that holds the world
      steps/steps-<opening>-<n>.log             the step log: every world's batches of a step,
                                                synced once for all (``steplog.py``)

A world exists exactly when its directory holds ``world.json``. Creation builds the
directory under a temporary name and renames it into place (a failure removes the
half-built directory at once); deletion renames it away before removing it, so a crash
never leaves half a world in the catalog. A directory holding a log or snapshots but no
``world.json`` is damage, reported by ``orphans`` and refused at start-up like any other.

The data directory is watched: its identity (device and inode, and those of ``worlds/``)
is recorded when it is opened and checked after every round of log syncs, before every
catalog change and around every snapshot. A directory deleted or replaced under a running
server disables writes (``WritesDisabled``, 503) instead of acknowledging edits that the
next start would not find. Other failed file operations of the catalog raise
``StorageError`` naming the file and the OS error.

Every opening of a world for writing (creation, a restart, a move to another engine) takes
the next **epoch**: it writes ``epoch`` first (atomically, so as a new file), then reads the
log and starts a segment of the new epoch, which fences what older epochs write later
(``recovery``). The holder of an older epoch finds out after its next sync: ``epoch`` is no
longer the file it wrote (or the world's directory moved away), and its batches fail with
``WorldFenced`` instead of being acknowledged. A batch it appended before the new holder read
the log is in the new holder's history; one appended after is not; either way it was not
acknowledged, and a retry carrying its ``Idempotency-Key`` is applied exactly once.

``hand_over`` moves a world's directory to another engine's data directory (a rename on the
shared file system) and ``take_over`` fetches it from there when its holder does not answer.

``Storage`` owns the group-commit thread shared by every world's log; ``WorldStore`` is one
world's handle: ``append`` a batch (a future that completes once it is durable), ``snapshot``
the voxels (then the log is trimmed), ``close``.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import shutil
import uuid
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import numpy as np

from sdfserver.errors import CorruptData, InvalidInput, NotFound, StorageError, WorldFenced, WritesDisabled
from sdfserver.incoming import short
from sdfserver.storage.codec import encode_batch
from sdfserver.storage.committer import Committer, SyncError
from sdfserver.storage.fsutil import fsync_dir, truncate_durably, write_atomic
from sdfserver.storage.recovery import Recovered, recover_world
from sdfserver.storage.snapshot import SNAPSHOT_PATTERN, remove_snapshot_files, write_snapshot
from sdfserver.storage.steplog import STEP_DIR, StepLog, replay
from sdfserver.storage.wal import SEGMENT_LIMIT_BYTES, SEGMENT_PATTERN, WorldLog, segment_epoch

log = logging.getLogger("sdfserver.storage")
DEFAULT_DATA_DIR = "data"  # relative to the working directory; see docs/configuration.md
WORLD_ID = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9_.-]{0,127}$")  # never a leading dot
META_FILE = "world.json"
EPOCH_FILE = "epoch"
_HIDDEN = "."  # prefix of directories being created or deleted


def check_world_id(world_id: str) -> str:
    if not isinstance(world_id, str) or not WORLD_ID.match(world_id):
        raise InvalidInput(f"world id must match {WORLD_ID.pattern}, got {short(world_id)}")
    return world_id


class WorldStore:
    """One world's durable state. ``append`` is thread-safe; ``snapshot`` and ``close`` are
    meant for the thread that owns the world."""

    def __init__(self, world_id: str, directory: Path, log: WorldLog, epoch: int = 0):
        self.world_id = world_id
        self.directory = directory
        self.log = log
        self.snapshot_version = 0
        self.records_since_snapshot = 0
        self.epoch = epoch
        self.fenced: WorldFenced | None = None
        self._epoch_path = str(directory / EPOCH_FILE)  # a string: asked after every sync of this world
        self._epoch_file = _file_identity(self._epoch_path)
        log.fence = self.check_fence

    def check_fence(self) -> WorldFenced | None:
        """Why this holder may no longer acknowledge writes (another took the world), or None."""
        if self.fenced is None and _file_identity(self._epoch_path) != self._epoch_file:
            self.fenced = WorldFenced(f"world {self.world_id!r} is now held by another engine (this one held "
                                     f"epoch {self.epoch}); nothing it did not acknowledge counts")
        return self.fenced

    @property
    def last_version(self) -> int:
        return self.log.last_version

    def append(self, version: int, edits_wire: Any) -> Future:
        """Log one batch; the future completes when it is durable (acknowledge after that)."""
        return self.append_many(version, [edits_wire])

    def append_many(self, first_version: int, batches_wire: list[Any], *, wake: bool = True) -> Future:
        """Log consecutive batches with one write; one future for all of them (``wake`` as in
        ``Committer.submit``)."""
        future = self.log.append_many(first_version, [encode_batch(b) for b in batches_wire], wake=wake)
        self.records_since_snapshot += len(batches_wire)
        return future

    def append_unsynced(self, first_version: int, batches_wire: list[Any]) -> list[bytes]:
        """Log consecutive batches, held by the log until its next sync (the step log makes them
        durable: ``steplog.py``); returns their payloads."""
        payloads = [encode_batch(b) for b in batches_wire]
        self.log.append_unsynced(first_version, payloads)
        self.records_since_snapshot += len(batches_wire)
        return payloads

    def snapshot(self, version: int, config: dict[str, Any], voxels: np.ndarray) -> None:
        """Persist the voxels at ``version`` and trim the log to the records after it.

        ``version`` at most the last logged version is an ordinary checkpoint: the log goes on
        in its segment (appends never wait for a snapshot) and loses the segments the snapshot
        covers. A version above it records a replacement of the whole world (an import or
        upload): the log starts over after it."""
        self.log.committer.verify()
        if self.check_fence() is not None:
            raise self.fenced
        try:
            path = write_snapshot(self.directory, version, config, voxels)
        except OSError:
            self.log.committer.verify()  # a vanished directory disables writes, not just this snapshot
            raise
        if self.check_fence() is not None:  # taken over while writing: what it holds may be fenced
            path.unlink(missing_ok=True)
            raise self.fenced
        self.log.committer.verify()
        if version > self.log.last_version:
            self.log.rotate(version)
        self.log.trim(version)
        self.snapshot_version = version
        self.records_since_snapshot = self.log.last_version - version

    def write_meta(self, meta: dict[str, Any]) -> None:
        """Replace the catalog entry durably; on failure the old entry stands whole."""
        self.log.committer.verify()
        path = self.directory / META_FILE
        try:
            write_atomic(path, json.dumps(meta, sort_keys=True, indent=1).encode())
        except OSError as exc:
            self.log.committer.verify()
            raise StorageError(f"cannot write {path}: {exc}") from None

    def close(self) -> None:
        self.log.close()


class Storage:
    def __init__(self, data_dir: str | Path = DEFAULT_DATA_DIR, *, sync: bool = True,
                 commit_window_ms: float = 0.0, segment_limit: int = SEGMENT_LIMIT_BYTES,
                 sync_inline: bool = False):
        self.segment_limit = segment_limit
        self.data_dir = Path(data_dir).expanduser().resolve()
        self.worlds_dir = self.data_dir / "worlds"
        try:
            self.worlds_dir.mkdir(parents=True, exist_ok=True)
            self._identities = [(str(d), _identity(os.stat(d))) for d in (self.data_dir, self.worlds_dir)]
        except OSError as exc:
            raise StorageError(f"cannot create the data directory {self.worlds_dir}: {exc}") from None
        self.committer = Committer(sync=sync, window_ms=commit_window_ms, inline=sync_inline,
                                   guard=self.moved)
        self._sweep()
        try:  # the opening's number: an engine's epoch, one more each time it starts
            self.epoch = _read_epoch(self.data_dir) + 1
            write_atomic(self.data_dir / EPOCH_FILE, f"{self.epoch}\n".encode())
            replay(self.data_dir / STEP_DIR, self.worlds_dir)  # before any world's log is read
            # the step log only where batches are synced: without syncs there is nothing to share
            self.steps = StepLog(self.data_dir / STEP_DIR, self.committer, self.epoch) if sync else None
        except OSError as exc:
            self.committer.close()
            raise StorageError(f"cannot open the data directory {self.data_dir}: {exc}") from None
        except BaseException:
            self.committer.close()
            raise

    def moved(self) -> SyncError | None:
        """Why the data directory is no longer the one opened (deleted, replaced), or None."""
        for path, identity in self._identities:
            try:
                if _identity(os.stat(path)) == identity:
                    continue
                cause = OSError(errno.ENOENT, "the directory was replaced by another one while the server ran")
            except OSError as exc:
                cause = exc
            return path, "the check", cause
        return None

    def check(self) -> None:
        """Raise ``WritesDisabled`` if writes are disabled or the data directory moved."""
        self.committer.verify()

    def _sweep(self) -> None:
        """Finish what a crash interrupted: half-created or half-deleted world directories."""
        for leftover in self.worlds_dir.glob(_HIDDEN + "*"):
            shutil.rmtree(leftover, ignore_errors=True)

    def _dir(self, world_id: str) -> Path:
        return self.worlds_dir / check_world_id(world_id)

    # -- the catalog -------------------------------------------------------------------------

    def world_ids(self) -> list[str]:
        return sorted(p.parent.name for p in self.worlds_dir.glob("*/" + META_FILE)
                      if not p.parent.name.startswith(_HIDDEN))

    def orphans(self) -> dict[str, str]:
        """World directories with a log or snapshots but no catalog entry: {world id: directory}."""
        found = {}
        for directory in self.worlds_dir.iterdir():
            if directory.name.startswith(_HIDDEN) or not directory.is_dir() or (directory / META_FILE).exists():
                continue
            if any(directory.glob(SEGMENT_PATTERN)) or any(directory.glob(SNAPSHOT_PATTERN)):
                found[directory.name] = str(directory)
        return found

    def read_meta(self, world_id: str) -> dict[str, Any]:
        path = self._dir(world_id) / META_FILE
        try:
            return json.loads(path.read_bytes())
        except FileNotFoundError:
            raise NotFound(f"no stored world {world_id!r}") from None
        except ValueError as exc:
            raise CorruptData(str(path), None, f"catalog entry is not JSON: {exc}") from None

    def catalog(self) -> dict[str, dict[str, Any]]:
        return {world_id: self.read_meta(world_id) for world_id in self.world_ids()}

    # -- worlds ------------------------------------------------------------------------------

    def create_world(self, world_id: str, meta: dict[str, Any], *, voxels: np.ndarray | None = None,
                     version: int = 0) -> WorldStore:
        """A new world at ``version`` (with an initial snapshot when ``voxels`` is given)."""
        final = self._dir(world_id)
        self.check()
        if final.exists():
            raise InvalidInput(f"world {world_id!r} already exists in {self.worlds_dir}")
        staging = self.worlds_dir / f"{_HIDDEN}new-{world_id}-{uuid.uuid4().hex[:8]}"
        try:
            staging.mkdir()
            write_atomic(staging / META_FILE, json.dumps(meta, sort_keys=True, indent=1).encode())
            write_atomic(staging / EPOCH_FILE, b"1\n")
            if voxels is not None:
                write_snapshot(staging, version, meta["config"], voxels)
            segment = WorldLog.create_segment(staging, version, epoch=1)
            fsync_dir(staging)
            staging.rename(final)
            staging = final  # from here a failure removes the world's directory itself
            fsync_dir(self.worlds_dir)
            segment = final / segment.name
            recovered = Recovered(version, voxels, last_version=version, segment=segment,
                                  segment_end=segment.stat().st_size)
            return self._attach(world_id, final, recovered, epoch=1)
        except OSError as exc:
            shutil.rmtree(staging, ignore_errors=True)  # what is left of it, if anything, goes at the next start
            self.check()
            raise StorageError(f"cannot create world {world_id!r} in {self.worlds_dir}: {exc}") from None

    def open_world(self, world_id: str) -> tuple[WorldStore, Recovered]:
        """Recover a stored world under a new epoch (see the module docstring); raises
        ``CorruptData`` when it cannot be trusted."""
        directory = self._dir(world_id)
        if not (directory / META_FILE).exists():
            raise NotFound(f"no stored world {world_id!r}")
        self.check()
        try:
            epoch = max(_read_epoch(directory), max_segment_epoch(directory)) + 1
            write_atomic(directory / EPOCH_FILE, f"{epoch}\n".encode())  # first: it fences the holder before
        except OSError as exc:
            raise StorageError(f"cannot take world {world_id!r} in {directory}: {exc}") from None
        recovered = recover_world(directory)
        if recovered.fenced_records:
            log.warning("world %s: ignored %d log records written by an engine after another took the world "
                        "over (none of them was acknowledged)", world_id, recovered.fenced_records)
        if recovered.torn and recovered.segment is not None:
            truncate_durably(recovered.segment, recovered.segment_end)
        recovered.segment = None  # the new epoch writes a segment of its own
        return self._attach(world_id, directory, recovered, epoch), recovered

    def hand_over(self, world_id: str, store: WorldStore, destination: Path) -> None:
        """Move a world's directory into the data directory ``destination`` (another engine's on
        the same file system), its log closed first so that all it holds is durable."""
        store.close()
        self._move(self._dir(world_id), Path(destination) / "worlds" / check_world_id(world_id))

    def take_over(self, world_id: str, source: Path) -> None:
        """Fetch a world's directory from the data directory ``source`` (another engine's, which
        does not answer) unless it is here already: its holder, if it still runs, is fenced by
        the epoch ``open_world`` takes next."""
        here = self._dir(world_id)
        if not here.exists():
            self._move(Path(source) / "worlds" / check_world_id(world_id), here)
        try:  # what the holder acknowledged from its step log and had not synced in the world's own
            replay(Path(source) / STEP_DIR, self.worlds_dir, only_world=world_id)
        except OSError as exc:
            raise StorageError(f"cannot read the step log of {source}: {exc}") from None

    def _move(self, origin: Path, target: Path) -> None:
        self.check()
        if not (origin / META_FILE).exists():
            raise NotFound(f"no stored world {origin.name!r} in {origin.parent}")
        if target.exists():
            raise InvalidInput(f"world {target.name!r} already exists in {target.parent}")
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            origin.rename(target)
            fsync_dir(target.parent)
            fsync_dir(origin.parent)
        except OSError as exc:
            raise StorageError(f"cannot move world {origin.name!r} from {origin.parent} to {target.parent}: "
                               f"{exc}") from None

    def _attach(self, world_id: str, directory: Path, recovered: Recovered, epoch: int) -> WorldStore:
        segment, end = recovered.segment, recovered.segment_end
        if segment is None:
            segment = WorldLog.create_segment(directory, recovered.last_version, epoch)
            end = segment.stat().st_size
        log = WorldLog(directory, self.committer, segment, end, recovered.last_version, self.segment_limit)
        store = WorldStore(world_id, directory, log, epoch)
        store.snapshot_version = recovered.snapshot_version
        store.records_since_snapshot = recovered.last_version - recovered.snapshot_version
        log.trim(recovered.snapshot_version)
        return store

    def delete_world(self, world_id: str, store: WorldStore | None = None) -> None:
        """Remove a world: renamed away first (a failure changes nothing), then its log is closed
        and its files removed."""
        directory = self._dir(world_id)
        self.check()
        if not directory.exists():
            raise NotFound(f"no stored world {world_id!r}")
        doomed = self.worlds_dir / f"{_HIDDEN}del-{world_id}-{uuid.uuid4().hex[:8]}"
        try:
            directory.rename(doomed)
            fsync_dir(self.worlds_dir)
        except OSError as exc:
            self.check()
            raise StorageError(f"cannot delete world {world_id!r} from {self.worlds_dir}: {exc}") from None
        if store is not None:
            try:
                store.close()
            except WritesDisabled as exc:  # the world is out of the catalog: deleted all the same
                log.warning("world %s is deleted; closing its log failed: %s", world_id, exc)
        try:
            remove_snapshot_files(doomed)
            shutil.rmtree(doomed)
        except OSError as exc:  # already out of the catalog; the next start sweeps what is left
            log.warning("world %s is deleted but %s could not be removed: %s", world_id, doomed, exc)

    def close(self) -> None:
        try:
            if self.steps is not None:
                self.steps.close()
        finally:
            self.committer.close()


def _identity(st: os.stat_result) -> tuple[int, int]:
    return st.st_dev, st.st_ino


def _file_identity(path: str | Path) -> tuple[int, int, int] | None:
    """Which file ``path`` is now (a replacement is another inode, or the same inode reused
    later than it was written), or None when there is none."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_mtime_ns


def _read_epoch(directory: Path) -> int:
    try:
        return int((directory / EPOCH_FILE).read_text().strip() or 0)
    except FileNotFoundError:
        return 0  # a world written before epochs
    except ValueError as exc:
        raise CorruptData(str(directory / EPOCH_FILE), 0, f"not an epoch number: {exc}") from None


def max_segment_epoch(directory: Path) -> int:
    return max((segment_epoch(p) for p in directory.glob(SEGMENT_PATTERN)), default=0)
