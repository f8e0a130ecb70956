"""What a recompute did (``RecomputeResult``: the regions rewritten, device and wall time, each
algorithm's figures) and one still on the device (``PendingRecompute``: a step starts every
touched world's recompute, then waits for the device once). Re-exported by ``world.py``."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.stats import AlgorithmStats, summarize
from sdfserver.geometry import Box

if TYPE_CHECKING:
    from sdfserver.algorithms.base import Pieces
    from sdfserver.world import World


@dataclass
class RecomputeResult:
    regions: list[Box]  # rewritten: chunk-aligned, no two touching (merge_regions)
    chunk_size: int
    device_ms: float = 0.0  # summed kernel time from profiling events
    wall_ms: float = 0.0
    iterations: int = 0
    kernel_ms: list[float] = field(default_factory=list)  # each launch, in order
    algorithms: dict[str, AlgorithmStats] = field(default_factory=dict)  # per algorithm run

    def iterations_of(self, algorithm: str) -> int:
        stats = self.algorithms.get(algorithm)
        return 0 if stats is None else stats.iterations

    @property
    def bandwidth_gbps(self) -> float | None:
        """The exact transform's achieved bandwidth in this recompute (GB/s; exact.bytes_moved
        says what is counted), or None where exact did not run."""
        stats = self.algorithms.get("exact")
        return None if stats is None else stats.bandwidth_gbps

    @property
    def changed_chunk_count(self) -> int:
        return sum(r.chunk_range(self.chunk_size).volume for r in self.regions)

    @property
    def changed_chunks(self) -> np.ndarray:
        """(N, 3) int32 chunk coordinates (x, y, z) rewritten; built only when asked for (publishing
        reads the regions), since a 256^3 world under cap 255 rewrites all 4096 chunks a step."""
        ranges = [r.chunk_range(self.chunk_size) for r in self.regions]
        if not ranges:
            return np.zeros((0, 3), dtype=np.int32)
        # The regions do not touch, so neither do their chunk ranges: no chunk twice.
        return np.concatenate([
            np.stack(np.meshgrid(*(np.arange(lo, hi, dtype=np.int32) for lo, hi in zip(c.lo, c.hi)),
                                 indexing="ij"), axis=-1).reshape(-1, 3) for c in ranges])


@dataclass
class PendingRecompute:
    """A recompute enqueued on the device (``World.begin_recompute``), finished by ``finish``:
    after the device is done, the field's version moves and the figures are summed. One left in
    ``pieces`` is enqueued by ``advance``, a piece at a time, before it can finish."""

    world: "World"
    regions: list[Box]
    runs: list
    started: float
    version: int  # the version the field will reflect
    pieces: "Pieces | None" = None  # the work not yet enqueued; None: all of it is
    pieces_run: int = 0
    # The worlds of a stacked run (``stacked.py``) share one list that holds their runs' summary
    # once the first of them has made it: the same launches, the same share of each.
    shared_summary: list | None = None

    def summary(self) -> tuple[list[float], dict[str, AlgorithmStats], float, int]:
        """``stats.summarize`` of the runs (the device done with them), with their device time and
        iterations summed; made once for a stacked run."""
        if self.shared_summary is None:
            return self._summarize()
        if not self.shared_summary:
            self.shared_summary.append(self._summarize())
        return self.shared_summary[0]

    def _summarize(self) -> tuple[list[float], dict[str, AlgorithmStats], float, int]:
        each, by_algorithm = summarize(self.runs)
        return each, by_algorithm, sum(each), sum(run.iterations for _, run in self.runs)

    @property
    def in_pieces(self) -> bool:
        return self.pieces is not None

    def advance(self, budget_s: float, interrupted: Callable[[], bool] = lambda: False) -> bool:
        """Enqueue pieces, waiting for the device after each, until ``budget_s`` has passed or
        ``interrupted()`` (one piece at least) or none is left; True when none is left and the
        device is done."""
        if self.pieces is None:
            return True
        started, queue = time.perf_counter(), self.world.gpu.queue
        for _ in self.pieces:
            queue.finish()
            self.pieces_run += 1
            if time.perf_counter() - started >= budget_s or interrupted():
                return False
        queue.finish()
        self.pieces = None
        return True

    def cancel(self) -> None:
        """Stop enqueuing (the world goes away); what was enqueued runs out first."""
        if self.pieces is not None:
            self.pieces.close()
            self.pieces = None
            try:
                self.world.gpu.queue.finish()
            except cl.Error:  # the device is lost: nothing runs out
                pass

    def finish(self, device_done: bool = False) -> RecomputeResult:
        """``device_done``: the caller has waited for the device already (one wait for a step's
        worlds)."""
        if self.pieces is not None:
            raise RuntimeError("a recompute in pieces finishes only once advance() has run them all")
        return self.world._finish_recompute(self, device_done)
