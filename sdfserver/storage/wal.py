"""The write-ahead log of one world (its segments and their names).

``WorldLog.append(version, payload)`` writes one framed record with ``os.write`` (under the
log's lock, so records of one world are in version order; ``append_many`` writes several
consecutive records with one ``os.write``) and hands the file to the ``Committer``
(``committer.py``); it returns a ``concurrent.futures.Future`` that completes once the record is
durable. Block on it with ``.result()`` or await it with ``asyncio.wrap_future``; acknowledge
the batch only after that. ``append_unsynced`` takes records that the step log (``steplog.py``)
makes durable: it holds them in memory, and they are written with the next sync of the file (a
checkpoint, a rotation, ``close``) in one ``os.write``, so that an engine step that touched
many worlds makes one write, the step log's, instead of one a world. A segment that has grown
past ``segment_limit`` bytes is closed and the next append starts a new one, so snapshots never
rotate the log (which would hold up the appender) and the log is trimmed a whole segment at a
time.
"""

from __future__ import annotations

import fcntl
import os
import threading
from concurrent.futures import Future
from pathlib import Path

from sdfserver.errors import WritesDisabled
from sdfserver.storage.committer import Committer, Fence, linked
from sdfserver.storage.framing import encode_record, encode_segment_header
from sdfserver.storage.fsutil import fsync_dir, write_atomic

SEGMENT_PATTERN = "wal-*.log"
SEGMENT_LIMIT_BYTES = 16 << 20  # some 160k records of a brush or two (~100 bytes each)


def segment_name(base_version: int, epoch: int = 0) -> str:
    """``wal-<base>.log`` (epoch 0, logs written before epochs) or ``wal-<base>-e<epoch>.log``."""
    return f"wal-{base_version:020d}.log" if epoch == 0 else f"wal-{base_version:020d}-e{epoch}.log"


def segment_base(path: Path) -> int:
    return int(path.stem.split("-")[1])


def segment_epoch(path: Path) -> int:
    parts = path.stem.split("-")
    return int(parts[2][1:]) if len(parts) > 2 else 0


def history_order(path: Path) -> tuple[int, int]:
    """Segments sorted by this key are in the order they were written: epoch, then base."""
    return segment_epoch(path), segment_base(path)


class WorldLog:
    """Appends to the newest segment of one world's log directory."""

    def __init__(self, directory: Path, committer: Committer, segment: Path, end: int, last_version: int,
                 segment_limit: int = SEGMENT_LIMIT_BYTES):
        self.directory = Path(directory)
        self.committer = committer
        self.segment_limit = segment_limit
        self.epoch = segment_epoch(segment)  # new segments carry it too
        self.fence: Fence | None = None  # set by the world's store (WorldStore.check_fence)
        self._lock = threading.Lock()
        self._path = segment
        self._fd = os.open(segment, os.O_WRONLY | os.O_APPEND)
        self._end = end
        os.ftruncate(self._fd, end)  # drop a torn tail recovery decided to truncate
        os.fsync(self._fd)
        self.last_version = last_version  # of the records appended, held ones included
        self.unsynced = False  # appended by append_unsynced since its last sync
        self._unsynced_writes = 0  # append_unsynced calls, so that a sync knows what it covered
        # append_unsynced's records not written yet, framed: bytes, which the garbage collector
        # does not walk (a list of them would make each full collection walk every held record)
        self._held = bytearray()
        self._held_after = 0  # the version the first held record follows

    @staticmethod
    def create_segment(directory: Path, base_version: int, epoch: int = 0) -> Path:
        """A new, empty segment, created atomically and durably."""
        path = Path(directory) / segment_name(base_version, epoch)
        write_atomic(path, encode_segment_header(base_version))
        return path

    @property
    def segment(self) -> Path:
        return self._path

    def segments(self) -> list[Path]:
        return sorted(self.directory.glob(SEGMENT_PATTERN), key=history_order)

    def append(self, version: int, payload: bytes) -> Future:
        return self.append_many(version, [payload])

    def append_many(self, first_version: int, payloads: list[bytes], *, wake: bool = True) -> Future:
        """Records ``first_version``, ``first_version + 1``, ... in one write; one future for all
        (``wake`` as in ``Committer.submit``)."""
        with self._lock:
            self._hold_locked(first_version, payloads)
            # written at once: never also written by a take-over, which replays step-log entries only
            self._write_held_locked(guard_take_over=False)
            return self.committer.submit(self._fd, str(self._path), wake=wake, fence=self.fence)

    def append_unsynced(self, first_version: int, payloads: list[bytes]) -> None:
        """``append_many`` without a write or a sync: the step log (``steplog.py``) makes them
        durable, and its checkpoint, a rotation or ``close`` writes and syncs them."""
        with self._lock:
            self._hold_locked(first_version, payloads)
            self.unsynced = True
            self._unsynced_writes += 1

    def sync_written(self) -> None:
        """Write and sync what ``append_unsynced`` took, if anything; raises OSError when the
        write or the sync fails or the file is no longer linked (what it holds would be lost).
        The sync runs on a copy of the descriptor, outside the lock, so that the engine's appends
        do not wait for it (a rotation or close meanwhile has synced the file itself)."""
        with self._lock:
            self._write_held_locked()
            if not self.unsynced or self._fd < 0:
                return
            fd, path, covered = os.dup(self._fd), str(self._path), self._unsynced_writes
        try:
            os.fdatasync(fd)
            problem = linked(fd, path)
        finally:
            os.close(fd)
        if problem is not None:
            raise problem[2]
        with self._lock:
            if self._unsynced_writes == covered:
                self.unsynced = False

    def _hold_locked(self, first_version: int, payloads: list[bytes]) -> None:
        self.committer.check()
        if self._fd < 0:
            raise WritesDisabled(f"the log of {self.directory.name} is closed")
        if first_version != self.last_version + 1:
            raise ValueError(f"log of {self.directory.name}: version {first_version} follows "
                             f"{self.last_version}; versions must be continuous")
        if not self._held:
            self._held_after = self.last_version
        self._held += b"".join([encode_record(first_version + i, p) for i, p in enumerate(payloads)])
        self.last_version = first_version + len(payloads) - 1

    def _write_held_locked(self, guard_take_over: bool = True) -> None:
        """Write the held records in one ``os.write``, in a new segment if this one is full;
        drop them if another engine took the world over (``fence``): that engine's take-over
        wrote what this one acknowledged from its step log, and the rest was never
        acknowledged. The check and the write hold the segment's ``flock``, which the take-over's
        replay takes too (``steplog._restore_world``), so the records are written once."""
        if not self._held or self._fd < 0:
            return
        self.committer.check()
        if guard_take_over and self._dropped_if_taken_over():  # no segment of ours in its directory
            return
        if self._end >= self.segment_limit:
            try:
                self._rotate_locked(self._held_after)
            except OSError as exc:
                raise self.committer.fail(str(self.directory), "rotation", exc) from None
        if guard_take_over:
            fcntl.flock(self._fd, fcntl.LOCK_EX)
        try:
            if guard_take_over and self._dropped_if_taken_over():
                return
            frame, self._held = self._held, bytearray()
            view = memoryview(frame)
            try:
                while view:
                    view = view[os.write(self._fd, view):]
            except OSError as exc:
                try:  # leave no partial record for a later append to follow
                    os.ftruncate(self._fd, self._end)
                except OSError:
                    pass  # the failed state below refuses every later append anyway
                raise self.committer.fail(str(self._path), "write", exc) from None
            self._end += len(frame)
        finally:
            if guard_take_over:
                fcntl.flock(self._fd, fcntl.LOCK_UN)

    def _dropped_if_taken_over(self) -> bool:
        """Whether another engine holds the world now; if so the held records are dropped."""
        if self.fence is None or self.fence() is None:
            return False
        self._held = bytearray()
        return True

    def _flush_locked(self) -> None:
        self.committer.submit(self._fd, str(self._path)).result()

    def flush(self) -> None:
        """Wait until everything appended so far is durable."""
        with self._lock:
            self._flush_locked()

    def rotate(self, base_version: int | None = None) -> None:
        """Continue in a new segment based at ``base_version`` (default: the last version).
        A base above the last version starts over after a snapshot that replaced the world."""
        with self._lock:
            self._write_held_locked()
            base = self.last_version if base_version is None else base_version
            if base < self.last_version:
                raise ValueError(f"cannot rotate to base {base} below the last version {self.last_version}")
            if base == self.last_version and self._end == len(encode_segment_header(0)) \
                    and segment_base(self._path) == base:
                return  # already an empty segment at that base
            self._rotate_locked(base)

    def _rotate_locked(self, base: int) -> None:
        """Continue at ``base``: the last version written, or past the last appended (a world
        replaced whole); held records stay held for the new segment."""
        self.committer.check()
        self._flush_locked()  # syncs what append_unsynced wrote too: the old file is closed next
        self.unsynced = bool(self._held)
        path = self.create_segment(self.directory, base, self.epoch)
        fsync_dir(self.directory)  # its name durable too, before records synced in it are acknowledged
        os.close(self._fd)
        self._fd = os.open(path, os.O_WRONLY | os.O_APPEND)
        self._path, self._end = path, len(encode_segment_header(0))
        self.last_version = max(self.last_version, base)

    def trim(self, upto_version: int) -> list[Path]:
        """Delete the segments whose records are all ``<= upto_version``; returns them."""
        with self._lock:
            segments = self.segments()
            doomed = [seg for seg, nxt in zip(segments, segments[1:])
                      if segment_base(nxt) <= upto_version and seg != self._path]
            for seg in doomed:
                seg.unlink()
            if doomed:
                fsync_dir(self.directory)
            return doomed

    def close(self) -> None:
        with self._lock:
            if self._fd >= 0:
                try:
                    if self.committer.failure is None and not self.committer.closed:
                        self._write_held_locked()
                        self._flush_locked()
                finally:
                    os.close(self._fd)
                    self._fd = -1
