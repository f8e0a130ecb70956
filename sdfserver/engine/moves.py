"""Worlds leaving this engine for another one, and arriving from one (engine thread).

A move is two commands, each run in its step's order with the edits around it:

- ``ReleaseWorld`` on the engine that holds the world: the batches before it are applied and
  their log records made durable (so they are acknowledged), its snapshot finished, its log
  closed, and its directory renamed into the other engine's data directory; the world leaves
  the device and a tombstone answers ``WorldMoved`` for it, so that a request that comes later
  is asked again where the world is now; its subscriptions are told they ended (the API's
  stream subscribes again where the world went).
- ``AdoptWorld`` on the engine that takes it: the directory fetched from the old holder's data
  directory if that one did not hand it over (it does not answer; it is fenced by the new
  epoch), the world rebuilt from its snapshot and log (``rebuild.restore_world``) and served.

A world another engine took over while this one still held it (``journal.fenced``) is dropped
the same way when the next batch for it comes.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from sdfserver.engine.batches import BatchPipeline
from sdfserver.engine.commands import EngineLimits
from sdfserver.engine.rebuild import restore_world
from sdfserver.engine.subscriptions import Subscriptions
from sdfserver.engine.worlds import WorldTable
from sdfserver.errors import InvalidInput
from sdfserver.gpu import GpuContext

log = logging.getLogger("sdfserver.engine")


class Moves:
    def __init__(self, gpu: GpuContext, limits: EngineLimits, table: WorldTable, batches: BatchPipeline,
                 subscriptions: Subscriptions, journal: Any):
        self.gpu = gpu
        self.limits = limits
        self.table = table
        self.batches = batches
        self.subscriptions = subscriptions
        self.journal = journal

    def _storage_journal(self) -> Any:
        if self.journal is None or not hasattr(self.journal, "hand_over"):
            raise InvalidInput("moving a world needs a data directory on storage every engine reaches "
                               "(persist is off)")
        return self.journal

    def release(self, world_id: str, destination: Path) -> None:
        self.table.get(world_id)
        self._storage_journal().hand_over(world_id, destination)
        self._leave(world_id, f"world {world_id!r} moved to another engine")

    def adopt(self, world_id: str, source: Path | None) -> dict[str, Any]:
        journal = self._storage_journal()
        if world_id in self.table.worlds:
            raise InvalidInput(f"world {world_id!r} is already on this engine")
        if source is not None:
            journal.take_over(world_id, source)
        restored = restore_world(self.gpu, self.limits, journal.storage, world_id)
        self.table.adopt(world_id, restored.world, restored.owner)
        self.batches.remember(world_id, restored.batch_ids)
        journal.adopt(world_id, restored.store, restored.owner)
        log.info("world %s adopted at epoch %d (%d logged batches replayed)", world_id, restored.store.epoch,
                 restored.replayed)
        return self.table.describe(world_id)

    def drop_if_fenced(self, world_id: str) -> None:
        """Forget a world another engine took over (its files are that engine's now)."""
        if self.journal is None or world_id not in self.table.worlds or not self.journal.fenced(world_id):
            return
        log.warning("world %s was taken over by another engine; dropped here", world_id)
        self.journal.forget(world_id)
        self._leave(world_id, f"world {world_id!r} was taken over by another engine")

    def _leave(self, world_id: str, why: str) -> None:
        self.table.forget(world_id, why)
        self.subscriptions.drop_world(world_id, why)
        self.batches.forget_world(world_id)
