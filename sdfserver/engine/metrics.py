"""The engine's Prometheus metrics, registered on a registry the caller owns.

A registry per engine (not the process-global one) lets tests and several
apps live in one process.
"""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

RECOMPUTE_BUCKETS_S = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)


class EngineMetrics:
    def __init__(self, registry: CollectorRegistry | None = None):
        self.registry = registry = registry or CollectorRegistry()
        self._children: dict[tuple[object, str], object] = {}
        self.edit_ops = Counter("sdfserver_edit_ops", "Edit operations applied.", registry=registry)
        self.edit_batches = Counter("sdfserver_edit_batches", "Edit batches applied.", registry=registry)
        self.rejected_batches = Counter("sdfserver_rejected_batches", "Edit batches rejected (nothing applied).",
                                        registry=registry)
        self.steps = Counter("sdfserver_engine_steps", "Engine steps run.", registry=registry)
        self.step_seconds = Histogram("sdfserver_engine_step_seconds", "Wall time of one engine step.",
                                      buckets=RECOMPUTE_BUCKETS_S, registry=registry)
        self.phase_seconds = Counter("sdfserver_engine_phase_seconds", "Engine-thread wall time by step phase "
                                     "(apply, recompute, publish, serve).", ["phase"], registry=registry)
        self.recompute_seconds = Histogram(
            "sdfserver_recompute_seconds", "Wall time of one world's recompute, by algorithm.",
            ["algorithm"], buckets=RECOMPUTE_BUCKETS_S, registry=registry)
        self.recompute_device_seconds = Counter(
            "sdfserver_recompute_device_seconds", "Kernel time spent recomputing fields, by algorithm.",
            ["algorithm"], registry=registry)
        self.changed_chunks = Counter("sdfserver_changed_chunks", "Chunks rewritten by recomputes.",
                                      registry=registry)
        self.dirty_chunks = Gauge("sdfserver_dirty_chunks", "Dirty chunks over all worlds before a step's "
                                  "recompute, counted at most ten times a second.", registry=registry)
        self.queue_depth = Gauge("sdfserver_queue_depth", "Commands waiting for the engine.", registry=registry)
        self.worlds = Gauge("sdfserver_worlds", "Worlds in the server.", registry=registry)
        self.device_bytes = Gauge("sdfserver_device_bytes", "Device memory held by worlds.", registry=registry)
        self.subscribers = Gauge("sdfserver_stream_subscribers", "Field subscriptions.", registry=registry)
        self.pending_chunks = Gauge("sdfserver_stream_pending_chunks",
                                    "Chunks waiting in subscriber mailboxes (at most one per subscribed chunk).",
                                    registry=registry)
        self.pending_bytes = Gauge("sdfserver_stream_pending_bytes", "Bytes waiting in subscriber mailboxes.",
                                   registry=registry)
        self.merged_chunks = Counter("sdfserver_stream_merged_chunks",
                                     "Pending chunks replaced by newer data before a slow subscriber took them.",
                                     registry=registry)

    # Labelled children, looked up once: labels() validates and locks on every call (~3 us).
    def _labelled(self, metric, value: str):
        child = self._children.get((metric, value))
        if child is None:
            child = self._children[(metric, value)] = metric.labels(value)
        return child

    def phase(self, name: str) -> Counter:
        return self._labelled(self.phase_seconds, name)

    def recompute_by(self, algorithm: str) -> tuple[Histogram, Counter]:
        """The wall-time histogram and device-time counter of one algorithm."""
        return (self._labelled(self.recompute_seconds, algorithm),
                self._labelled(self.recompute_device_seconds, algorithm))
