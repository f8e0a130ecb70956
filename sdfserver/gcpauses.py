"""Garbage-collector pauses: keep start-up's objects out of them, and count them.

A full collection walks every tracked object with the GIL held, and start-up (FastAPI,
pydantic, numpy, pyopencl) leaves about 70,000 of them: some 30 ms a collection. Under load a
full collection came round about once a second and stalled the event loop and the engine
thread together; it was the service's whole p99. ``freeze_startup_objects`` moves everything
alive at start-up into the permanent generation, which the collector skips; ``GcPauses``
times every collection for ``/metrics``. API processes and engine processes do both, each after
its own start-up: an engine process holds as many start-up objects, and its full collection
would hold up its engine thread. An API process hands its numbers to its row of the table the
API processes share (``publish``, api/counts.py), so that ``/metrics`` shows all of theirs
whichever process answers (api/process_metrics.py).
"""

from __future__ import annotations

import gc
import time
from typing import Any, Callable, Iterator

from prometheus_client import CollectorRegistry
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

GENERATIONS = 3
# what a collection of each generation publishes (names made once: the callback only looks them up)
_NAMES = [(f"gc_collections_{g}", f"gc_seconds_{g}", f"gc_longest_{g}") for g in range(GENERATIONS)]


def freeze_startup_objects() -> int:
    """Collect once, then exempt every surviving object from later collections; returns how many."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


class GcPauses:
    """Counts collections and their wall time by generation.

    The callback runs inside the collector, on whichever thread triggered it: it only adds
    numbers to lists and writes them to shared memory (a metric's lock there could deadlock
    against the same thread)."""

    def __init__(self, registry: CollectorRegistry | None, prefix: str = "sdfserver_gc",
                 publish: Callable[[str, float], None] | None = None):
        """``prefix``: the metrics' names (an engine process's differ from an API process's:
        /metrics shows both). ``publish``: also hand each number to it by name as it changes
        (``gc_collections_<generation>``, ``gc_seconds_*``, ``gc_longest_*``, ``gc_frozen_objects``:
        an API process's row of ``api.counts.SharedCounts``); ``registry`` None: shown only there."""
        self.prefix = prefix
        self.count = [0] * GENERATIONS
        self.seconds = [0.0] * GENERATIONS
        self.longest = [0.0] * GENERATIONS
        self._started = 0.0
        self._registry = registry
        self._publish = publish
        if publish is not None:
            publish("gc", 1.0)
            publish("gc_frozen_objects", float(gc.get_freeze_count()))
        gc.callbacks.append(self._callback)
        if registry is not None:
            registry.register(self)

    def _callback(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._started = time.perf_counter()
            return
        generation, pause = info["generation"], time.perf_counter() - self._started
        self.count[generation] += 1
        self.seconds[generation] += pause
        self.longest[generation] = max(self.longest[generation], pause)
        if self._publish is not None:
            self._publish(_NAMES[generation][0], self.count[generation])
            self._publish(_NAMES[generation][1], self.seconds[generation])
            self._publish(_NAMES[generation][2], self.longest[generation])

    def collect(self) -> Iterator[Any]:
        count = CounterMetricFamily(f"{self.prefix}_collections", "Garbage collections, by generation.",
                                    labels=["generation"])
        seconds = CounterMetricFamily(f"{self.prefix}_pause_seconds", "Wall time spent in garbage collections "
                                      "(the GIL is held throughout), by generation.", labels=["generation"])
        longest = GaugeMetricFamily(f"{self.prefix}_longest_pause_seconds", "The longest garbage collection so "
                                    "far, by generation.", labels=["generation"])
        for g in range(GENERATIONS):
            count.add_metric([str(g)], self.count[g])
            seconds.add_metric([str(g)], self.seconds[g])
            longest.add_metric([str(g)], self.longest[g])
        yield count
        yield seconds
        yield longest
        yield GaugeMetricFamily(f"{self.prefix}_frozen_objects", "Objects exempted from garbage collection "
                                "at start-up.", value=gc.get_freeze_count())

    def close(self) -> None:
        gc.callbacks.remove(self._callback)
        if self._registry is not None:
            self._registry.unregister(self)
