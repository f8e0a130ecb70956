"""The load generator's own garbage collector, kept out of the latencies it measures.

A full collection walks every object the process holds (the HTTP client, asyncio, numpy: about
55,000) with the GIL held, stalling every client of the process at once, and that pause would
count as the server's. ``settle`` collects once and freezes what is alive before the run;
``FullCollections`` counts the full collections during it and the longest, for the report.
"""

from __future__ import annotations

import gc
import time
from typing import Any

OLDEST = 2  # the generation a full collection collects


def settle() -> int:
    """Collect, then exempt everything alive from later collections; how many objects that is."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


class FullCollections:
    """``with FullCollections() as full:`` counts the full collections run inside the block."""

    def __init__(self) -> None:
        self.count = 0
        self.longest_s = 0.0
        self._started = 0.0

    def __enter__(self) -> "FullCollections":
        gc.callbacks.append(self._callback)
        return self

    def __exit__(self, *exc: Any) -> None:
        gc.callbacks.remove(self._callback)

    def _callback(self, phase: str, info: dict[str, Any]) -> None:
        if info["generation"] != OLDEST:
            return
        if phase == "start":
            self._started = time.perf_counter()
        else:
            self.count += 1
            self.longest_s = max(self.longest_s, time.perf_counter() - self._started)
