"""The group-commit thread shared by every log of an engine: what an append hands it is synced,
and its future completed, a round at a time.

Two ways to sync, chosen per server (``sync_inline``):

- inline: the appending thread calls ``fdatasync`` right after its write and
  gets back a future that is already complete. The engine appends once per step (the step log,
  ``steplog.py``), so every batch of a step shares that sync; on a disk that syncs in tens of
  microseconds this is the shortest path to an acknowledgement (no thread hand-offs, no wait
  for the GIL).
- group commit (the default): the committer thread takes every record waiting (optionally
  after a short window), calls ``fdatasync`` once per file, and completes all their futures
  together. While one sync runs, the appends that arrive queue up for the next, and the engine
  goes on. After its appends the engine calls ``hand_over``: if the committer was idle, the
  engine waits (GIL released) until it has taken every queued record, so the sync starts at
  once: otherwise the committer would wait for the GIL while the engine works on, and the
  sync would start up to a switch interval late (measured on the H200 host: 0.49 ms of the
  1.69 ms a one-client edit spent in the server).

A failed write or sync is never retried: the committer enters a failed state, every waiting
future and every later append raises ``WritesDisabled`` naming the file and the OS error.
What reached the disk before the failure is recovered at the next start as usual.

A sync that succeeds is not enough: ``fdatasync`` of a file whose directory was deleted
succeeds too, and the data is gone at the next start. So after each round of syncs, before
any future completes, every synced file must still be linked (``st_nlink``) and the
``guard`` (``Storage``: the data directory is still the one opened) must pass; otherwise
the committer fails as for a failed sync and the batches are not acknowledged.
"""

from __future__ import annotations

import contextlib
import errno
import os
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable, ContextManager

from sdfserver.errors import WritesDisabled
from sdfserver.threadnames import name_os_thread

SYNC_THREADS = 8
HANDOVER_TIMEOUT_S = 0.005  # a committer not scheduled by then: go on, the record stays queued
SyncError = tuple[str, str, OSError]  # (path, what failed, the error)
Fence = Callable[[], "Exception | None"]  # after a sync: why its records must not be acknowledged


class Committer:
    """One thread that makes appended records durable, many at a time."""

    def __init__(self, *, sync: bool = True, window_ms: float = 0.0, inline: bool = False,
                 guard: Callable[[], SyncError | None] | None = None):
        self.sync = sync
        self.guard = guard  # checked after every round of syncs, before anything is acknowledged
        self.inline = inline
        self.window_s = max(0.0, window_ms) / 1e3
        self._cond = threading.Condition()
        self._pending: list[tuple[int, str, Future, Fence | None]] = []
        self._failure: WritesDisabled | None = None
        self._closed = False
        self._idle = False  # the committer waits for records
        self._queued = 0  # records ever queued, of those taken for a sync, and of those settled
        self._taken = 0
        self._settled = 0  # durable (or failed) and their futures completed
        self.syncs = 0  # fdatasync calls made
        self.records = 0  # records made durable
        self._pool = ThreadPoolExecutor(max_workers=SYNC_THREADS, thread_name_prefix="sdfserver-fdatasync",
                                        initializer=name_os_thread)
        # a round's futures are completed inside this: the engine process's transport sends the
        # acknowledgements they release together (EngineTransport.holding)
        self.completing: Callable[[], ContextManager[Any]] = contextlib.nullcontext
        self._thread = threading.Thread(target=self._run, name="sdfserver-wal-sync", daemon=True)
        self._thread.start()

    @property
    def failure(self) -> WritesDisabled | None:
        return self._failure

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def waiting(self) -> int:
        """Records handed over but not yet taken for a sync."""
        with self._cond:
            return len(self._pending)

    def check(self) -> None:
        if self._failure is not None:
            raise self._failure
        if self._closed:
            raise WritesDisabled("the write-ahead log is closed")

    def verify(self) -> None:
        """``check``, then the guard: a guard that fails disables writes here and now."""
        self.check()
        problem = self.guard() if self.guard is not None else None
        if problem is not None:
            raise self.fail(*problem)

    def fail(self, path: str, what: str, exc: BaseException) -> WritesDisabled:
        with self._cond:
            if self._failure is None:
                self._failure = WritesDisabled(
                    f"writes are disabled: {what} of {path} failed ({exc}); nothing after the last "
                    "acknowledged edit is kept, and no edit is accepted until the server is restarted")
                pending, self._pending = self._pending, []
                self._taken = self._settled = self._queued
                self._cond.notify_all()
                for _, _, future, _ in pending:
                    future.set_exception(self._failure)
            return self._failure

    def submit(self, fd: int, path: str, *, wake: bool = True, fence: Fence | None = None) -> Future:
        """A future completed once everything written to ``fd`` so far is durable.

        ``wake=False`` leaves an idle committer asleep until ``hand_over``: a caller appending
        to several files calls it once after the last, so they share one round of syncs (an
        early wake would take the first file alone while the next ``os.write`` lets go of the
        GIL). ``fence``, asked after the sync, may refuse this file's records (its world moved
        to another engine): the future fails with what it returns, the other files go on."""
        future: Future = Future()
        if not self.sync:
            problem = self._after_sync({fd: path})
            if problem is not None:
                future.set_exception(self.fail(*problem))
            else:
                complete(future, fence() if fence is not None else None)
            return future
        if self.inline:
            self.check()
            error = self._sync_one((fd, path)) or self._after_sync({fd: path})
            if error is not None:
                future.set_exception(self.fail(*error))
                return future
            self.syncs += 1
            self.records += 1
            complete(future, fence() if fence is not None else None)
            return future
        with self._cond:
            self.check()
            self._pending.append((fd, path, future, fence))
            self._queued += 1
            if wake or self.window_s:
                self._cond.notify_all()
        return future

    def hand_over(self, wait: bool = True) -> None:
        """Wake the committer for what is queued; if it was idle, wait (GIL released) until it
        has taken all of it, at most HANDOVER_TIMEOUT_S (with a commit window, or ``wait``
        false: do not wait)."""
        if not self.sync or self.inline:
            return
        with self._cond:
            if not self._pending:
                return
            self._cond.notify_all()
            if wait and self._idle and not self.window_s:
                queued = self._queued
                self._cond.wait_for(lambda: self._taken >= queued or self._closed, HANDOVER_TIMEOUT_S)

    def wait_settled(self, timeout_s: float) -> bool:
        """Wait (GIL released) until every record handed over so far is durable and its future
        completed, or has failed; at most ``timeout_s``. True once they are."""
        if not self.sync or self.inline:
            return True
        with self._cond:
            queued = self._queued
            return self._cond.wait_for(lambda: self._settled >= queued or self._closed, timeout_s)

    def _run(self) -> None:
        name_os_thread()
        while True:
            with self._cond:
                self._idle = True
                while not self._pending and not self._closed:
                    self._cond.wait()
                self._idle = False
                if not self._pending:
                    return
            if self.window_s:
                time.sleep(self.window_s)
            with self._cond:
                batch, self._pending = self._pending, []
                self._taken = taken = self._queued
                self._cond.notify_all()  # an append waiting for the hand-over goes on
            files = {fd: path for fd, path, _, _ in batch}
            # Several files (worlds) sync side by side, so the file system can merge them, each
            # sync thread taking its share of the files in turn (a pool task a file cost the
            # engine's GIL a hand-off a file); one share syncs right here (a pool round trip
            # costs two more waits for the GIL under load).
            shares = _shares(list(files.items()), SYNC_THREADS)
            if len(shares) == 1:
                results = [self._sync_share(shares[0])]
            else:
                results = list(self._pool.map(self._sync_share, shares))
            # a failed sync first, then the guard's cause (the data directory moved), then a
            # deleted log file
            errors = sorted((e for e in results if e is not None), key=lambda e: e[1] != "fdatasync")
            if not errors or errors[0][1] != "fdatasync":
                problem = self.guard() if self.guard is not None else None
                errors = [problem] if problem is not None else errors
            with self.completing():
                if errors:
                    failure = self.fail(*errors[0])
                    for _, _, future, _ in batch:
                        future.set_exception(failure)
                else:
                    self.syncs += len(files)
                    self.records += len(batch)
                    refusals: dict[int, Exception | None] = {}  # one fence check per file and round
                    for fd, _, future, fence in batch:
                        if fence is not None and fd not in refusals:
                            refusals[fd] = fence()
                        complete(future, refusals.get(fd))
            with self._cond:
                self._settled = max(self._settled, taken)
                self._cond.notify_all()  # an engine waiting for its step's acknowledgements goes on

    @staticmethod
    def _sync_one(item: tuple[int, str]) -> SyncError | None:
        fd, path = item
        try:
            os.fdatasync(fd)
        except OSError as exc:
            return path, "fdatasync", exc
        return None

    @staticmethod
    def _sync_share(items: list[tuple[int, str]]) -> SyncError | None:
        """Sync each file of ``items`` in turn, then check each is still linked (``_linked``);
        the first failed sync, else the first file unlinked, or None."""
        for item in items:
            problem = Committer._sync_one(item)
            if problem is not None:
                return problem
        return next(filter(None, (linked(*item) for item in items)), None)

    def _after_sync(self, files: dict[int, str]) -> SyncError | None:
        """Why records just synced would still be lost at the next start: the guard's cause (the
        data directory moved), or a log file deleted; None when they are safe."""
        problem = self.guard() if self.guard is not None else None
        if problem is not None:
            return problem
        for fd, path in files.items():
            problem = linked(fd, path)
            if problem is not None:
                return problem
        return None

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join()
        self._pool.shutdown()


def linked(fd: int, path: str) -> SyncError | None:
    """A log file deleted while the server ran: what it holds would be lost at the next start."""
    try:
        if os.fstat(fd).st_nlink > 0:
            return None
    except OSError as exc:
        return path, "fstat", exc
    return path, "the check", FileNotFoundError(errno.ENOENT, "the log file was deleted while the "
                                                "server ran, so what it holds would be lost")


def _shares(items: list, count: int) -> list[list]:
    """``items`` dealt into at most ``count`` lists of nearly equal length, none empty."""
    count = max(1, min(count, len(items)))
    return [items[i::count] for i in range(count)]


def complete(future: Future, refusal: Exception | None) -> None:
    """Complete a durable record's future: done, or failed with why it must not be acknowledged."""
    if refusal is None:
        future.set_result(None)
    else:
        future.set_exception(refusal)
