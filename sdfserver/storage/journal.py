"""The engine's durability hook (``sdfserver.engine.journal.Journal``) on the storage layer.

The engine calls it on its own thread:

- ``record_create`` creates the world's directory (catalog entry and an empty log);
- ``record_batches`` appends a step's batches for a world to its log (held there until the
  step log's checkpoint, which the step's record makes unnecessary for durability) and returns
  what completes once they are durable — the engine acknowledges them only then;
- ``start_syncs`` hands what the step appended to the committer (``Committer.hand_over``);
- ``wait_durable`` waits until the committer has acknowledged it (``Committer.wait_settled``);
- ``record_config`` rewrites the catalog entry before a reconfiguration takes effect;
- ``record_delete`` removes the world's directory;
- ``wants_snapshot`` / ``record_snapshot``: after a recompute, a world with
  ``snapshot_every_batches`` records since its last snapshot, and whose last snapshot started
  at least ``snapshot_min_interval_s`` ago, hands over a copy of its voxels (still being
  filled by the device); a background thread waits for it, writes the snapshot and trims
  the log. The interval keeps a busy world from snapshotting several times a second: each
  snapshot copies, compresses and writes every voxel of the world.

``adopt`` registers a world restored at start-up (``sdfserver.engine.restore``) or moved here;
``hand_over`` gives a world's directory to another engine's data directory (its snapshot
finished, its log closed: all of it durable), ``take_over`` fetches one from another engine
that does not answer, ``fenced`` tells whether another engine took a world of this one over.

Each hook either does all it was asked or raises before changing anything:
``WritesDisabled`` when writes are disabled or the data directory was deleted or replaced
(``Storage.moved``), ``StorageError`` for any other failed file operation.
"""

from __future__ import annotations

import logging
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable

import numpy as np

from sdfserver.errors import NotFound, SdfServerError
from sdfserver.storage.committer import complete
from sdfserver.storage.store import Storage, WorldStore
from sdfserver.threadnames import name_os_thread

log = logging.getLogger("sdfserver.storage")


class WorldDurable:
    """A world's share of a step's record in the step log, as a future's ``done``,
    ``exception``, ``result`` and ``add_done_callback``: durable once the record is, failed with
    the record's error, or with the world's fence (another engine took it over). The worlds of a
    step share one future (``shared``; ``fence`` is the world's own part), since a future a world
    cost the engine thread a lock and a condition each (most of what a world added to a step's
    log record)."""

    __slots__ = ("shared", "_store")

    def __init__(self, step: Future, store: WorldStore):
        self.shared = step
        self._store = store

    def done(self) -> bool:
        return self.shared.done()

    def fence(self) -> BaseException | None:
        """Why this world's records, though durable, must not be acknowledged, or None."""
        return self._store.check_fence()

    def exception(self, timeout: float | None = None) -> BaseException | None:
        error = self.shared.exception(timeout)
        return error if error is not None else self.fence()

    def result(self, timeout: float | None = None) -> None:
        error = self.exception(timeout)
        if error is not None:
            raise error

    def add_done_callback(self, fn: Callable[["WorldDurable"], None]) -> None:
        self.shared.add_done_callback(lambda _: fn(self))


class StorageJournal:
    def __init__(self, storage: Storage, *, snapshot_every_batches: int = 5000,
                 snapshot_min_interval_s: float = 0.0, clock: Callable[[], float] = time.monotonic):
        self.storage = storage
        self.snapshot_every_batches = snapshot_every_batches
        self.snapshot_min_interval_s = snapshot_min_interval_s
        self._clock = clock
        self._last_snapshot_at: dict[str, float] = {}  # when each world's last snapshot started
        self.stores: dict[str, WorldStore] = {}
        self.owners: dict[str, str | None] = {}
        self._snapshotting: dict[str, Future] = {}
        self._step: list[tuple[WorldStore, list]] = []  # record_batches since start_syncs
        self._step_durable: Future = Future()  # completed with the step log's record of them
        self._snapshots = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sdfserver-snapshot",
                                             initializer=name_os_thread)

    def _store(self, world_id: str) -> WorldStore:
        try:
            return self.stores[world_id]
        except KeyError:
            raise NotFound(f"world {world_id!r} has no log") from None

    def adopt(self, world_id: str, store: WorldStore, owner: str | None) -> None:
        self.stores[world_id] = store
        self.owners[world_id] = owner
        self._last_snapshot_at[world_id] = self._clock()

    # -- the engine's hook ------------------------------------------------------------------------

    def record_create(self, world_id: str, config: dict[str, Any], owner: str | None = None, *,
                      voxels: np.ndarray | None = None, version: int = 0) -> None:
        self.stores[world_id] = self.storage.create_world(world_id, {"config": config, "owner": owner},
                                                          voxels=voxels, version=version)
        self.owners[world_id] = owner
        self._last_snapshot_at[world_id] = self._clock()

    def record_batches(self, world_id: str, first_version: int,
                       batches: list[list[dict[str, Any]] | bytes]) -> Future | WorldDurable:
        store = self._store(world_id)
        if self.storage.steps is None:
            return store.append_many(first_version, batches, wake=False)  # see start_syncs
        payloads = store.append_unsynced(first_version, batches)  # durable with the step's record
        self._step.append((store, [world_id, store.epoch, first_version, payloads]))
        return WorldDurable(self._step_durable, store)

    def start_syncs(self, wait: bool = True) -> None:
        """The step's batches to the committer: with the step log, one record of every world's,
        whose sync completes the future the step's worlds share."""
        step, self._step = self._step, []
        shared, self._step_durable = self._step_durable, Future()
        if step:
            try:
                durable = self.storage.steps.append([entry for _, entry in step], [s.log for s, _ in step])
            except Exception as exc:  # not durable: the engine applies none of them (BatchPipeline.run)
                shared.set_exception(exc)
                return
            durable.add_done_callback(lambda done: complete(shared, done.exception()))
        self.storage.committer.hand_over(wait)

    def wait_durable(self, timeout_s: float) -> bool:
        return self.storage.committer.wait_settled(timeout_s)

    def record_config(self, world_id: str, config: dict[str, Any]) -> None:
        self._store(world_id).write_meta({"config": config, "owner": self.owners.get(world_id)})

    def record_delete(self, world_id: str) -> None:
        self._wait_snapshot(world_id)
        self.storage.delete_world(world_id, self.stores.get(world_id))  # raises before changing anything
        self.stores.pop(world_id, None)
        self.owners.pop(world_id, None)
        self._last_snapshot_at.pop(world_id, None)

    def wants_snapshot(self, world_id: str) -> bool:
        store = self.stores.get(world_id)
        busy = world_id in self._snapshotting and not self._snapshotting[world_id].done()
        return (store is not None and not busy and self.storage.committer.failure is None
                and store.records_since_snapshot >= self.snapshot_every_batches
                and self._clock() - self._last_snapshot_at.get(world_id, 0.0) >= self.snapshot_min_interval_s)

    def record_snapshot(self, world_id: str, version: int, config: dict[str, Any], voxels: np.ndarray,
                        ready: Callable[[], None]) -> Future:
        store = self._store(world_id)
        future = self._snapshots.submit(self._snapshot, store, version, config, voxels, ready)
        self._snapshotting[world_id] = future
        self._last_snapshot_at[world_id] = self._clock()
        return future

    # -- the rest ------------------------------------------------------------------------------------

    @staticmethod
    def _snapshot(store: WorldStore, version: int, config: dict[str, Any], voxels: np.ndarray,
                  ready: Callable[[], None]) -> None:
        try:
            ready()  # the device copy of the voxels
            store.snapshot(version, config, voxels)
        except Exception:  # the log still holds everything; the next snapshot tries again
            log.exception("snapshot of world %s at version %d failed", store.world_id, version)
            raise

    def _wait_snapshot(self, world_id: str) -> None:
        future = self._snapshotting.pop(world_id, None)
        if future is not None:
            future.exception()  # waits; a failure was logged by _snapshot

    def hand_over(self, world_id: str, destination: Path) -> None:
        """After this, the world is another engine's to open; on failure its log is open again here."""
        self._wait_snapshot(world_id)
        store = self._store(world_id)
        try:
            self.storage.hand_over(world_id, store, destination)
        except BaseException:
            reopened, _ = self.storage.open_world(world_id)  # a new epoch: everything logged is in it
            self.stores[world_id] = reopened
            raise
        self.stores.pop(world_id, None)
        self.owners.pop(world_id, None)
        self._last_snapshot_at.pop(world_id, None)

    def take_over(self, world_id: str, source: Path) -> None:
        self.storage.take_over(world_id, source)

    def epoch_of(self, world_id: str) -> int:
        store = self.stores.get(world_id)
        return 0 if store is None else store.epoch

    def fenced(self, world_id: str) -> bool:
        store = self.stores.get(world_id)
        return store is not None and store.fenced is not None

    def forget(self, world_id: str) -> None:
        """A world another engine took over: its log closed here, its files left alone."""
        store = self.stores.pop(world_id, None)
        self.owners.pop(world_id, None)
        self._last_snapshot_at.pop(world_id, None)
        if store is not None:
            try:
                store.close()
            except Exception as exc:  # the directory may be gone from here: nothing of it is ours now
                log.warning("closing the log of world %s, taken over by another engine: %s", world_id, exc)

    def close(self) -> None:
        """Close every world's log (what it appended made durable first). A log that cannot be
        made durable now (writes disabled, the data directory deleted) is said in the log, not
        raised: everything acknowledged was durable already, and the others still close."""
        self._snapshots.shutdown(wait=True)
        for world_id, store in self.stores.items():
            try:
                store.close()
            except SdfServerError as exc:
                log.warning("closing the log of world %s: %s", world_id, exc)
        self.stores.clear()
        self.storage.close()
