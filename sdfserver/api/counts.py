"""Counts of what happens to connections below the app — a WebSocket peer closed for not reading,
a connection refused at accept, an accept that failed — shared by every API process, and what
each API process says about itself (its pid, its garbage collector's numbers).

A scrape of ``/metrics`` reaches one API process, so these live in shared memory: the launcher
makes one table before it forks the API processes, each process adds to its own row (a replaced
process takes over the row of the one it replaces, so nothing counted is lost), and any process
reads the sum of the rows, or every row's values (``process_metrics.py``). A row has one writer,
so no lock is needed. ``CountsCollector`` shows the counts in an API process's Prometheus
registry. Log lines about the same events go through ``ThrottledLog``: an attack makes thousands
of them, and one line every few seconds with how many were left out says as much.
"""

from __future__ import annotations

import ctypes
import logging
import multiprocessing
import time
from typing import Iterator

from prometheus_client.core import CounterMetricFamily

COUNTS = ("websocket_send_timeouts", "refused_max_connections", "refused_descriptors", "accept_failures")
_INDEX = {name: i for i, name in enumerate(COUNTS)}
GC_GENERATIONS = 3
# A process's own values: its pid (0: the row is unclaimed), whether it counts its garbage
# collections (gcpauses.GcPauses, in server processes), and those by generation: how many, their
# seconds, the longest; and the objects it froze out of the collector.
VALUES = ("pid", "gc", *(f"gc_{what}_{g}" for what in ("collections", "seconds", "longest")
                         for g in range(GC_GENERATIONS)), "gc_frozen_objects")
_VALUE_INDEX = {name: i for i, name in enumerate(VALUES)}


class SharedCounts:
    def __init__(self, processes: int = 1):
        self._table = multiprocessing.RawArray(ctypes.c_int64, max(1, processes) * len(COUNTS))
        self._values = multiprocessing.RawArray(ctypes.c_double, max(1, processes) * len(VALUES))
        self._processes = max(1, processes)
        self._row = 0

    def for_process(self, row: int) -> "SharedCounts":
        """The same table, adding to row ``row`` (the API process's slot in the launcher)."""
        view = SharedCounts.__new__(SharedCounts)
        view._table, view._values, view._processes = self._table, self._values, self._processes
        view._row = row % self._processes
        return view

    @property
    def row(self) -> int:
        return self._row

    def add(self, name: str, n: int = 1) -> None:
        self._table[self._row * len(COUNTS) + _INDEX[name]] += n

    def total(self, name: str) -> int:
        index = _INDEX[name]
        return sum(self._table[row * len(COUNTS) + index] for row in range(self._processes))

    def claim(self, pid: int) -> None:
        """This process takes its row's values over (a replaced process's are dropped; its counts
        stay): its pid, for the others to read its ``/proc`` entry, and nothing else yet."""
        at = self._row * len(VALUES)
        self._values[at + 1:at + len(VALUES)] = [0.0] * (len(VALUES) - 1)
        self._values[at] = float(pid)

    def set(self, name: str, value: float) -> None:
        """One of this process's ``VALUES`` (a float, written whole: a reader sees the old or the new)."""
        self._values[self._row * len(VALUES) + _VALUE_INDEX[name]] = value

    def values(self) -> dict[int, dict[str, float]]:
        """Every claimed row's values (its process set a pid), by row."""
        rows = {}
        for row in range(self._processes):
            at = row * len(VALUES)
            if self._values[at]:
                rows[row] = dict(zip(VALUES, self._values[at:at + len(VALUES)]))
        return rows


class CountsCollector:
    """The shared counts as Prometheus counters (registered in each API process's registry)."""

    def __init__(self, counts: SharedCounts):
        self.counts = counts

    def collect(self) -> Iterator[CounterMetricFamily]:
        total = self.counts.total
        stalled = CounterMetricFamily(
            "sdfserver_websocket_send_timeouts", "WebSocket connections closed because their peer took none of "
            "the bytes waiting for it for ws_send_timeout_s")
        stalled.add_metric([], total("websocket_send_timeouts"))
        refused = CounterMetricFamily(
            "sdfserver_connections_refused", "Connections answered 503 and closed at accept: the API process "
            "held its share of max_connections, or as many as its file-descriptor limit leaves room for",
            labels=["reason"])
        refused.add_metric(["max_connections"], total("refused_max_connections"))
        refused.add_metric(["descriptors"], total("refused_descriptors"))
        failed = CounterMetricFamily(
            "sdfserver_accept_failures", "accept() calls on the listening socket that failed for want of file "
            "descriptors or memory (EMFILE, ENFILE, ENOBUFS, ENOMEM); the connection waits in the backlog")
        failed.add_metric([], total("accept_failures"))
        return iter([stalled, refused, failed])


class ThrottledLog:
    """At most one warning every ``every_s`` seconds; the next says how many were left out."""

    def __init__(self, logger: logging.Logger, every_s: float = 10.0):
        self.logger = logger
        self.every_s = every_s
        self.last = -float("inf")
        self.left_out = 0

    def warning(self, message: str, *args: object) -> None:
        now = time.monotonic()
        if now - self.last < self.every_s:
            self.left_out += 1
            return
        if self.left_out:
            message += f" ({self.left_out} more like it in the last {now - self.last:.0f} s)"
        self.last, self.left_out = now, 0
        self.logger.warning(message, *args)
