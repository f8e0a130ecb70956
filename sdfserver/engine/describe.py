"""A world's last recompute, as ``GET /v1/worlds/{id}`` describes it (docs/api.md)."""

from __future__ import annotations

from typing import Any

from sdfserver.world import RecomputeResult


def describe_recompute(result: RecomputeResult | None) -> dict[str, Any] | None:
    """What the last recompute did, per algorithm it ran; None before the first one.

    ``bandwidth_gbps`` is the exact transform's achieved bandwidth (``exact.bytes_moved`` over its
    device time), null where exact did not run."""
    if result is None:
        return None
    return {
        "wall_ms": result.wall_ms,
        "device_ms": result.device_ms,
        "changed_chunks": result.changed_chunk_count,
        "iterations": result.iterations,
        "bandwidth_gbps": result.bandwidth_gbps,
        "algorithms": {name: stats.as_dict() for name, stats in result.algorithms.items()},
    }
