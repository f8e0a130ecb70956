"""The subscriptions of one engine: who watches which region of which world, the current state
sent on subscribing, every recompute's changed chunks published to their mailboxes."""

from __future__ import annotations

import threading

from sdfserver.engine.metrics import EngineMetrics
from sdfserver.engine.mailbox import Subscription
from sdfserver.engine.publish import check_subscription_region, chunks_of, publish
from sdfserver.engine.worlds import WorldTable
from sdfserver.world import RecomputeResult


class Subscriptions:
    def __init__(self, table: WorldTable, max_voxels: int, metrics: EngineMetrics):
        self.table = table
        self.max_voxels = max_voxels
        self.metrics = metrics
        self._by_world: dict[str, set[Subscription]] = {}
        self._lock = threading.Lock()  # unsubscribe comes from any thread

    def subscribe(self, sub: Subscription) -> None:
        """Engine thread: the current state first, then every change, so none is missed."""
        world = self.table.get(sub.world_id)
        region = sub.region
        check_subscription_region(region, world.world_box, self.max_voxels)
        array = world.read_distance(region) if sub.format == "distance" else world.read_field(region)
        sub.mailbox.put(world.field_version, chunks_of(array, region.lo, region, world.config.chunk_size))
        with self._lock:
            self._by_world.setdefault(sub.world_id, set()).add(sub)
        self.count()

    def unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            subs = self._by_world.get(sub.world_id)
            if subs is not None:
                subs.discard(sub)
        self.count()
        self.count_pending()  # what its mailbox held leaves the gauges now, not at the next step

    def drop_world(self, world_id: str, why: str | None = None) -> None:
        """Forget the world's subscriptions; with ``why`` (it moved), each is told it ended."""
        with self._lock:
            subs = self._by_world.pop(world_id, set())
        if why is not None:
            for sub in subs:
                sub.mailbox.end(why)
        self.count()

    def publish(self, recomputed: dict[str, RecomputeResult]) -> None:
        for world_id, result in recomputed.items():
            with self._lock:
                subs = list(self._by_world.get(world_id, ()))
            if subs:
                self.metrics.merged_chunks.inc(publish(self.table.worlds[world_id], result, subs))

    def count(self) -> None:
        with self._lock:
            self.metrics.subscribers.set(sum(len(s) for s in self._by_world.values()))

    def count_pending(self) -> None:
        with self._lock:
            subs = [s for group in self._by_world.values() for s in group]
        self.metrics.pending_chunks.set(sum(s.mailbox.pending_chunks for s in subs))
        self.metrics.pending_bytes.set(sum(s.mailbox.pending_bytes for s in subs))
