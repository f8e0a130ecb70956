"""The engine's Prometheus metrics, registered on a registry the caller owns.

A registry per engine (not the process-global one) lets tests and several
apps live in one process.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Iterable

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

if TYPE_CHECKING:
    from sdfserver.world import RecomputeResult

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
                                     "(apply, durable, recompute, publish, serve).", ["phase"], registry=registry)
        self.recompute_seconds = Histogram(
            "sdfserver_recompute_seconds", "Wall time of one world's recompute, by algorithm.",
            ["algorithm"], buckets=RECOMPUTE_BUCKETS_S, registry=registry)
        self.recompute_device_seconds = Counter(
            "sdfserver_recompute_device_seconds", "Kernel time spent recomputing fields, by algorithm.",
            ["algorithm"], registry=registry)
        self.recompute_iterations = Counter(
            "sdfserver_recompute_iterations", "Passes counted by the algorithms that iterate (fim and jfa_fim: "
            "FIM passes that changed something; jfa: its passes), by algorithm.", ["algorithm"], registry=registry)
        self.recompute_last_iterations = Gauge(
            "sdfserver_recompute_last_iterations", "Those passes in the last recompute that ran the algorithm.",
            ["algorithm"], registry=registry)
        self.recompute_bytes = Counter(
            "sdfserver_recompute_bytes", "Device memory traffic counted by the algorithm (exact: 5 bytes per "
            "work-box voxel and 2 per region voxel), by algorithm.", ["algorithm"], registry=registry)
        self.recompute_bandwidth = Gauge(
            "sdfserver_recompute_bandwidth_bytes_per_second", "Achieved bandwidth of the last recompute that ran "
            "the algorithm: its counted bytes over its kernel time (exact only).", ["algorithm"], registry=registry)
        self.changed_chunks = Counter("sdfserver_changed_chunks", "Chunks rewritten by recomputes.",
                                      registry=registry)
        self.dirty_chunks = Gauge("sdfserver_dirty_chunks", "Dirty chunks over all worlds before a step's "
                                  "recompute, counted at most ten times a second.", registry=registry)
        self.busy_seconds = Gauge(
            "sdfserver_engine_busy_seconds", "How long the engine's running step has taken, once past busy_step_ms "
            "(0 otherwise): an engine held by one world's work (/readyz says which).", registry=registry)
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
        # counted by the API processes and reported to the engine, so that /metrics shows them all
        self.bytes_out = Counter("sdfserver_bytes_out", "Response and stream bytes sent (bodies and frames).",
                                 registry=registry)
        self.ws_clients = Gauge("sdfserver_websocket_clients", "Open WebSocket streams.", registry=registry)

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

    def observe_recompute(self, algorithm: str, result: RecomputeResult) -> None:
        """One world's recompute (``observe_recomputes``)."""
        self.observe_recomputes([(algorithm, result)])

    def observe_recomputes(self, recomputes: Iterable[tuple[str, RecomputeResult]]) -> None:
        """A step's recomputes, each (the world's algorithm, its result): each one's wall time
        under the world's algorithm; kernel time, passes and bytes under each algorithm it ran
        (a focus runs two), summed over the step and counted once (each count takes a lock)."""
        changed = 0
        sums: dict[str, list] = {}  # algorithm -> [device ms, passes, bytes, last passes, last bandwidth]
        for algorithm, result in recomputes:
            self._labelled(self.recompute_seconds, algorithm).observe(result.wall_ms / 1e3)
            changed += result.changed_chunk_count
            for name, stats in result.algorithms.items():
                found = sums.get(name)
                if found is None:
                    found = sums[name] = [0.0, 0, 0, 0, None]
                found[0] += stats.device_ms
                found[1] += stats.iterations
                found[3] = stats.iterations
                if stats.bytes_moved:
                    found[2] += stats.bytes_moved
                    bandwidth = stats.bandwidth_gbps
                    if bandwidth is not None:
                        found[4] = bandwidth
        if changed:
            self.changed_chunks.inc(changed)
        for name, (device_ms, passes, moved, last_passes, bandwidth) in sums.items():
            self._labelled(self.recompute_device_seconds, name).inc(device_ms / 1e3)
            self._labelled(self.recompute_iterations, name).inc(passes)
            self._labelled(self.recompute_last_iterations, name).set(last_passes)
            if moved:
                self._labelled(self.recompute_bytes, name).inc(moved)
            if bandwidth is not None:
                self._labelled(self.recompute_bandwidth, name).set(bandwidth * 1e9)
