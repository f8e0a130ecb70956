"""One log for every world of an engine: a step's batches made durable by one sync.

Each world's batches still go to its own log (``WorldLog``), but that log holds them in memory
and writes them only at its next sync (a checkpoint's, a rotation's, ``close``): neither
written nor synced before they are acknowledged. The step's batches of every world are
written, as one record, to the engine's step log (``<data_dir>/steps/steps-<o>-<n>.log``,
``o`` the data directory's opening: ``Storage.epoch``),
and that one file is synced by the committer: the acknowledgement waits for one ``fdatasync``
however many worlds the step touched, where one a world held every acknowledgement of a step
until the last world's sync.

A record is the step's entries, ``[world id, epoch, first version, [payload, ...]]`` each, in
the framing of a log segment (``framing.py``; a step segment's records are numbered from 1).
When a segment has grown past ``STEP_SEGMENT_LIMIT_BYTES`` the log goes on in the next one and
a checkpoint thread writes and syncs every world log appended to while the old one was current,
then deletes it: from then on those worlds' own logs hold what it held. A world log closed or
rotated is written and synced first (``WorldLog``), so the checkpoint only ever syncs open files.

``replay`` runs before anything reads a world's log: at start-up over this engine's step log,
and over another engine's when a world is taken from it (``Storage.take_over``). For each world
still here at the epoch an entry was written under, what the newest segment of its log lost of
the entries (a crash took records still held, or writes that were never synced: a torn tail,
or a hole with later records after it) is cut and written again from the entries; a log that
lost nothing is synced as it is (a process that died left its writes in the page cache only). A world whose log
misses versions that the step log does not hold either raises ``CorruptData``.
"""

from __future__ import annotations

import fcntl
import logging
import os
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

import msgpack

from sdfserver.errors import CorruptData, WritesDisabled
from sdfserver.storage.framing import SEGMENT_HEADER, encode_record, encode_segment_header, record_at, scan_segment
from sdfserver.storage.fsutil import fsync_dir, fsync_file, write_atomic
from sdfserver.storage.wal import SEGMENT_PATTERN, history_order, segment_base, segment_epoch
from sdfserver.threadnames import name_os_thread

if TYPE_CHECKING:
    from sdfserver.storage.committer import Committer
    from sdfserver.storage.wal import WorldLog

log = logging.getLogger("sdfserver.storage")
STEP_DIR = "steps"
STEP_PATTERN = "steps-*-*.log"
STEP_SEGMENT_LIMIT_BYTES = 8 << 20
Entry = tuple[str, int, int, list[bytes]]  # world id, epoch, first version, payloads


def step_segments(directory: Path, opening: int | None = None) -> list[Path]:
    """The step log's segments in the order written (of one ``opening``, or of all)."""
    found = [(tuple(int(n) for n in p.stem.split("-")[1:]), p) for p in Path(directory).glob(STEP_PATTERN)]
    return [p for key, p in sorted(found) if opening is None or key[0] == opening]


class StepLog:
    """The engine's step log (engine thread: ``append``; any thread: ``close``)."""

    def __init__(self, directory: Path, committer: "Committer", opening: int,
                 segment_limit: int = STEP_SEGMENT_LIMIT_BYTES):
        """``opening``: the data directory's (``Storage.epoch``), which names the segments."""
        self.directory = Path(directory)
        self.committer = committer
        self.opening = opening
        self.segment_limit = segment_limit
        self.directory.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._number = 0
        self._fd = -1
        self._written: dict[int, "WorldLog"] = {}  # world logs appended to since the segment began
        self._checkpoints = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sdfserver-checkpoint",
                                               initializer=name_os_thread)
        self._open_segment()

    def _open_segment(self) -> None:
        self._number += 1
        self._path = self.directory / f"steps-{self.opening}-{self._number}.log"
        write_atomic(self._path, encode_segment_header(0))
        fsync_dir(self.directory)
        self._fd = os.open(self._path, os.O_WRONLY | os.O_APPEND)
        self._end, self._records = SEGMENT_HEADER.size, 0

    def append(self, entries: list[Entry], logs: list["WorldLog"]) -> Future:
        """Write a step's entries (each world's batches, already in ``logs``) as one record; the
        future completes once it is durable."""
        payload = msgpack.packb(entries, use_bin_type=True)
        with self._lock:
            self.committer.check()
            if self._end >= self.segment_limit:
                self._rotate_locked()
            frame = encode_record(self._records + 1, payload)
            view = memoryview(frame)
            try:
                while view:
                    view = view[os.write(self._fd, view):]
            except OSError as exc:
                raise self.committer.fail(str(self._path), "write", exc) from None
            self._end += len(frame)
            self._records += 1
            for world_log in logs:
                self._written[id(world_log)] = world_log
            return self.committer.submit(self._fd, str(self._path), wake=False)

    def _rotate_locked(self) -> None:
        old, written = self._path, list(self._written.values())
        self._close_locked()  # its records durable first: the committer may still hold its descriptor
        self._written = {}
        try:
            self._open_segment()
        except OSError as exc:
            raise self.committer.fail(str(self.directory), "rotation", exc) from None
        self._checkpoints.submit(self._checkpoint, old, written)

    def _checkpoint(self, segment: Path, written: list["WorldLog"]) -> None:
        """Write and sync the world logs appended to while ``segment`` was current, then delete it."""
        try:
            for world_log in written:
                world_log.sync_written()
            segment.unlink()
            fsync_dir(self.directory)
        except Exception as exc:  # kept: the next start replays it; nothing more is acknowledged
            self.committer.fail(str(segment), "the checkpoint", exc)
            log.error("step log checkpoint of %s failed: %s", segment, exc)

    def _close_locked(self) -> None:
        """Close the current segment once the committer has synced what it was handed of it."""
        try:
            if self.committer.failure is None and not self.committer.closed:
                self.committer.submit(self._fd, str(self._path)).result()
        finally:
            os.close(self._fd)
            self._fd = -1

    def close(self) -> None:
        """Write and sync every world log appended to and delete this opening's segments (they
        hold nothing more); after a failure they stay, for the next start's replay."""
        with self._lock:
            if self._fd < 0:
                return
            written, self._written = list(self._written.values()), {}
            try:
                self._close_locked()
            except WritesDisabled as exc:
                log.warning("the step log %s stays for the next start: %s", self._path, exc)
        self._checkpoints.shutdown()
        if self.committer.failure is not None:
            return
        try:
            for world_log in written:
                world_log.sync_written()
        except OSError as exc:
            log.warning("the step log %s stays for the next start: %s", self._path, exc)
            return
        for segment in step_segments(self.directory, self.opening):
            segment.unlink()
        fsync_dir(self.directory)


def replay(directory: Path, worlds_dir: Path, only_world: str | None = None) -> dict[str, int]:
    """Write back into the world logs under ``worlds_dir`` what they lost of the step log in
    ``directory`` (see the module docstring); returns how many records each world got back.
    Without ``only_world`` the step log's segments are deleted afterwards."""
    segments = step_segments(directory)
    entries: dict[str, list[tuple[int, int, list[bytes]]]] = {}
    for i, segment in enumerate(segments):
        scan = scan_segment(segment.read_bytes(), str(segment), 0)
        if scan.torn_at is not None and i < len(segments) - 1:
            raise CorruptData(str(segment), scan.torn_at, f"bad step record ({scan.torn_reason}) in a "
                              "segment that a newer one follows")
        for _, payload in scan.records:
            for world_id, epoch, first, payloads in msgpack.unpackb(payload, raw=False):
                if only_world is None or world_id == only_world:
                    entries.setdefault(world_id, []).append((epoch, first, payloads))
    restored = {}
    for world_id, found in entries.items():
        count = _restore_world(Path(worlds_dir) / world_id, found)
        if count:
            restored[world_id] = count
            log.warning("world %s: %d acknowledged log records were back from the step log %s",
                        world_id, count, directory)
    if only_world is None:
        for segment in segments:
            segment.unlink()
        if segments:
            fsync_dir(directory)
    return restored


def _restore_world(directory: Path, found: list[tuple[int, int, list[bytes]]]) -> int:
    segments = sorted(directory.glob(SEGMENT_PATTERN), key=history_order)
    if not segments:
        return 0  # deleted, or moved away: its log is elsewhere
    newest = segments[-1]
    epoch, base = segment_epoch(newest), segment_base(newest)
    records = [(first + i, p) for e, first, payloads in found if e == epoch for i, p in enumerate(payloads)]
    if not records:
        return 0  # written under another epoch: fenced, never acknowledged
    fd = os.open(newest, os.O_WRONLY)
    try:
        # a holder that still runs writes what it held under this lock, unless fenced (WorldLog)
        fcntl.flock(fd, fcntl.LOCK_EX)
        data = memoryview(newest.read_bytes())
        offset, last = SEGMENT_HEADER.size, base
        while offset < len(data):  # up to the first record that is not whole, whatever follows it
            version, end, why = record_at(data, offset)
            if why or version != last + 1:
                break
            offset, last = end, version
        missing = [(v, p) for v, p in records if v > last]
        if not missing:  # whole, but perhaps only in the page cache: durable before the step log goes
            fsync_file(newest)
            return 0
        if missing[0][0] != last + 1:
            raise CorruptData(str(newest), offset, f"the log ends at version {last} and the step log "
                              f"holds versions from {missing[0][0]}: versions in between are lost")
        os.ftruncate(fd, offset)
        os.lseek(fd, offset, os.SEEK_SET)
        frame = memoryview(b"".join(encode_record(v, p) for v, p in missing))
        while frame:
            frame = frame[os.write(fd, frame):]
        os.fsync(fd)
    finally:
        os.close(fd)
    return len(missing)
