"""What ``/metrics`` says about the API processes and the build, the same whichever API process
answers the scrape.

- ``process_*`` (prometheus_client's ``ProcessCollector``: CPU seconds, resident and virtual
  memory, open and most file descriptors, start time) of every API process, each labelled with
  its slot, ``api_process="<n>"`` (a replaced process takes its predecessor's slot). Each process
  leaves its pid in its row of the table the API processes share (``counts.py``); the one that
  answers reads every pid's ``/proc`` entry itself, so the figures are as fresh as the scrape.
  The API processes run on one host, beside their launcher.
- ``sdfserver_gc_*``: the API processes' garbage collections (``gcpauses.GcPauses``), published
  to the same table as they happen: counts and seconds summed over the processes, the longest
  pause the longest of any; the frozen objects summed. A replaced API process starts its part
  again from zero, as a restarted process's counters do.
- ``sdfserver_build_info{version}``: 1, the version (``sdfserver.__version__``) as a label.

The engines' figures come from the engines themselves (``Engines.metrics_text``).
"""

from __future__ import annotations

from typing import Iterator

from prometheus_client import ProcessCollector
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric

from sdfserver import __version__
from sdfserver.api.counts import GC_GENERATIONS, SharedCounts

LABEL = "api_process"


class ApiProcessesCollector:
    """Registered in each API process's registry (``app.ApiMetrics``)."""

    def __init__(self, counts: SharedCounts):
        self.counts = counts
        self._readers: dict[int, ProcessCollector] = {}  # by pid

    def collect(self) -> Iterator[Metric]:
        rows = self.counts.values()
        yield from self._processes(rows)
        if any(v["gc"] for v in rows.values()):
            yield from _collections(rows)
        info = GaugeMetricFamily("sdfserver_build_info", "The server's version, as a label; always 1.",
                                 labels=["version"])
        info.add_metric([__version__], 1)
        yield info

    def _processes(self, rows: dict[int, dict[str, float]]) -> Iterator[Metric]:
        families: dict[str, Metric] = {}
        pids = {int(v["pid"]) for v in rows.values()}
        self._readers = {pid: self._readers.get(pid) or _reader(pid) for pid in pids}
        for row, values in sorted(rows.items()):  # one /proc read per API process
            for family in self._readers[int(values["pid"])].collect():  # none for a process gone meanwhile
                merged = families.setdefault(family.name, Metric(family.name, family.documentation, family.type))
                merged.samples += [s._replace(labels={**s.labels, LABEL: str(row)}) for s in family.samples]
        return iter(families.values())


def _reader(pid: int) -> ProcessCollector:
    return ProcessCollector(pid=lambda: pid, registry=None)


def _collections(rows: dict[int, dict[str, float]]) -> Iterator[Metric]:
    """gcpauses.GcPauses's families, over every API process that publishes them."""
    values = [v for v in rows.values() if v["gc"]]
    count = CounterMetricFamily("sdfserver_gc_collections", "Garbage collections of the API processes, by "
                                "generation.", labels=["generation"])
    seconds = CounterMetricFamily("sdfserver_gc_pause_seconds", "Wall time the API processes spent in garbage "
                                  "collections (each holds its GIL throughout), by generation.", labels=["generation"])
    longest = GaugeMetricFamily("sdfserver_gc_longest_pause_seconds", "The longest garbage collection of any API "
                                "process so far, by generation.", labels=["generation"])
    for g in range(GC_GENERATIONS):
        count.add_metric([str(g)], sum(v[f"gc_collections_{g}"] for v in values))
        seconds.add_metric([str(g)], sum(v[f"gc_seconds_{g}"] for v in values))
        longest.add_metric([str(g)], max(v[f"gc_longest_{g}"] for v in values))
    frozen = GaugeMetricFamily("sdfserver_gc_frozen_objects", "Objects the API processes exempted from garbage "
                               "collection at start-up.", value=sum(v["gc_frozen_objects"] for v in values))
    return iter([count, seconds, longest, frozen])


__all__ = ["ApiProcessesCollector"]
