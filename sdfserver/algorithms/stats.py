"""What each algorithm did in one recompute: passes, device time and the bytes it counts.

A recompute can run two algorithms (``lod_algorithm`` over the region, the world's
algorithm inside the focus), so its figures are kept per algorithm name. They reach
``GET /v1/worlds/{id}``, ``/metrics`` and the benchmarks through ``RecomputeResult``.
"""

from __future__ import annotations

from dataclasses import dataclass

from sdfserver.algorithms.base import AlgorithmRun
from sdfserver.gpu.profiling import event_ms


@dataclass
class AlgorithmStats:
    regions: int = 0  # region jobs run
    iterations: int = 0  # the algorithm's own count (AlgorithmRun.iterations), summed over jobs
    device_ms: float = 0.0  # its launches' kernel time, from profiling events
    bytes_moved: int = 0  # device memory traffic, as the algorithm counts it (exact only; else 0)

    @property
    def bandwidth_gbps(self) -> float | None:
        """Achieved bandwidth, bytes_moved / device time, in GB/s (10^9 bytes a second);
        None where the algorithm counts no bytes or took no measurable time."""
        if self.bytes_moved <= 0 or self.device_ms <= 0.0:
            return None
        return self.bytes_moved / (self.device_ms * 1e6)

    def as_dict(self) -> dict:
        return {"regions": self.regions, "iterations": self.iterations, "device_ms": self.device_ms,
                "bytes_moved": self.bytes_moved, "bandwidth_gbps": self.bandwidth_gbps}


def summarize(runs: list[tuple[str, AlgorithmRun]]) -> tuple[list[float], dict[str, AlgorithmStats]]:
    """Each launch's kernel time in order, and the runs' figures per algorithm name. The
    events must be complete (the caller has finished the queue); a launch whose time the
    driver does not give counts as 0 ms."""
    kernel_ms: list[float] = []
    by_name: dict[str, AlgorithmStats] = {}
    for name, run in runs:
        each = [event_ms(e) or 0.0 for e in run.events]
        if run.share != 1.0:
            each = [t * run.share for t in each]
        kernel_ms.extend(each)
        stats = by_name.setdefault(name, AlgorithmStats())
        stats.regions += 1
        stats.iterations += run.iterations
        stats.device_ms += sum(each)
        stats.bytes_moved += run.bytes_moved
    return kernel_ms, by_name
