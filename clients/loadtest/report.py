"""The load test's reporting: the progress line, latency percentiles, the result document."""

from __future__ import annotations

import array
import sys
import time
from dataclasses import asdict
from typing import Any

import numpy as np

PERCENTILES = (50, 95, 99)


class ProgressLine:
    """One line on stderr, rewritten with \\r at most once a second."""

    def __init__(self, enabled: bool, requests: int, duration_s: float):
        self.enabled, self.requests, self.duration_s = enabled, requests, duration_s
        self.start = self.last = time.perf_counter()
        self.last_count = 0

    def update(self, count: int, errors: int, force: bool = False) -> None:
        now = time.perf_counter()
        if not self.enabled or (now - self.last < 1.0 and not force):
            return
        rate = (count - self.last_count) / max(now - self.last, 1e-9)
        self.last, self.last_count = now, count
        goal = f"/{self.requests}" if self.requests else ""
        sys.stderr.write(f"\r{now - self.start:6.1f}s/{self.duration_s:g}s  requests {count}{goal}  "
                         f"{rate:9.1f}/s  errors {errors}   ")
        sys.stderr.flush()

    def finish(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def latency_summary(samples: array.array, elapsed_s: float) -> dict:
    ms = np.frombuffer(samples, dtype=np.float64) if len(samples) else np.zeros(0)
    summary = {"count": int(ms.size), "throughput_per_s": ms.size / elapsed_s if elapsed_s > 0 else 0.0}
    if ms.size:
        pct = np.percentile(ms, PERCENTILES)
        summary["latency_ms"] = {**{f"p{p}": float(v) for p, v in zip(PERCENTILES, pct)},
                                 "mean": float(ms.mean()), "min": float(ms.min()), "max": float(ms.max())}
    return summary


def edit_timeline(tally: Any) -> list[dict]:
    """Edits per second of the run and their p99: shows whether the tail is steady or in bursts."""
    at = np.frombuffer(tally.edit_at_s, dtype=np.float64)
    ms = np.frombuffer(tally.edit_ms, dtype=np.float64)
    if not at.size:
        return []
    second = at.astype(np.int64)
    return [{"second": int(s), "edits": int(n), "p99_ms": float(np.percentile(ms[second == s], 99))}
            for s, n in zip(*np.unique(second, return_counts=True))]


def report(cfg: Any, tally: Any, elapsed_s: float, world: dict) -> dict:
    error_count = sum(tally.errors.values())
    return {
        "url": cfg.url,
        "world": world,
        "config": {**asdict(cfg), "api_key": "(set)" if cfg.api_key else None},  # never the key itself
        "elapsed_s": elapsed_s,
        "requests": tally.count,
        "throughput_rps": tally.answered / elapsed_s if elapsed_s > 0 else 0.0,  # answered, not failed
        "edits": latency_summary(tally.edit_ms, elapsed_s),
        "reads": latency_summary(tally.read_ms, elapsed_s),
        "round_trips": latency_summary(tally.round_trip_ms, elapsed_s),  # an edit and its min_version read
        "edit_timeline": edit_timeline(tally),
        "errors": {"count": error_count, "by_code": dict(sorted(tally.errors.items())),
                   "first_message": dict(sorted(tally.error_messages.items()))},
        # The load generator's own cost: if it nears the time a request takes, it measures itself.
        "client_cpu_us_per_request": tally.cpu_s / tally.count * 1e6 if tally.count else None,
        # Its own garbage collector: what was frozen before the run, and full collections during it.
        "client_gc": {"frozen_objects": tally.frozen_objects, "full_collections": tally.full_collections,
                      "longest_full_collection_ms": tally.longest_collection_s * 1e3},
    }


def format_report(result: dict) -> str:
    lines = [f"{result['requests']} requests in {result['elapsed_s']:.2f} s: "
             f"{result['throughput_rps']:.1f} requests/s, {result['errors']['count']} errors"]
    for kind in ("edits", "reads", "round_trips"):
        s = result.get(kind)
        if s and s["count"]:
            lat = s["latency_ms"]
            name = "edit+read" if kind == "round_trips" else kind
            lines.append(f"  {name:9s} {s['count']:8d}  {s['throughput_per_s']:9.1f}/s  "
                         f"p50 {lat['p50']:.2f} ms  p95 {lat['p95']:.2f} ms  p99 {lat['p99']:.2f} ms  "
                         f"max {lat['max']:.2f} ms")
    if result.get("client_cpu_us_per_request") is not None:
        lines.append(f"  load generator CPU {result['client_cpu_us_per_request']:.0f} us/request "
                     f"({result['config']['http']} HTTP client on {result['config']['loop']})")
    collector = result.get("client_gc")
    if collector is not None:
        lines.append(f"  load generator's full collections: {collector['full_collections']}, the longest "
                     f"{collector['longest_full_collection_ms']:.1f} ms ({collector['frozen_objects']} objects frozen "
                     "before the run)")
    for code, n in result["errors"]["by_code"].items():
        lines.append(f"  error {code}: {n}")
    return "\n".join(lines)
