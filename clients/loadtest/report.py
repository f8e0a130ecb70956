"""The load test's reporting: the progress line, latency percentiles, the result document."""

from __future__ import annotations

import array
import sys
import time
from dataclasses import asdict
from typing import Any

import numpy as np

PERCENTILES = (50, 95, 99)
LATE_MS = 1.0  # a send further than this past its slot left late (beyond the event loop timer's jitter)


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


def _ms(samples: array.array) -> np.ndarray:
    return np.frombuffer(samples, dtype=np.float64) if len(samples) else np.zeros(0)


def _percentiles(ms: np.ndarray) -> dict:
    pct = np.percentile(ms, PERCENTILES)
    return {**{f"p{p}": float(v) for p, v in zip(PERCENTILES, pct)},
            "mean": float(ms.mean()), "min": float(ms.min()), "max": float(ms.max())}


def latency_summary(samples: array.array, elapsed_s: float, service: array.array | None = None) -> dict:
    """Count, throughput and latency percentiles; with ``service`` (at a set rate) the service
    times beside them, each request timed from when it actually left."""
    ms = _ms(samples)
    summary = {"count": int(ms.size), "throughput_per_s": ms.size / elapsed_s if elapsed_s > 0 else 0.0}
    if ms.size:
        summary["latency_ms"] = _percentiles(ms)
    if service is not None and len(service):
        summary["service_time_ms"] = _percentiles(_ms(service))
    return summary


def schedule_summary(cfg: Any, tally: Any) -> dict:
    """How the requests were paced and what latency counts from (loadtest.schedule); at a set rate,
    how many left late and by how much."""
    if cfg.rate <= 0:
        return {"loop": "closed", "latency_from": "send"}
    lag = _ms(tally.send_lag_ms)
    return {
        "loop": "open", "rate_per_s": cfg.rate, "latency_from": "due",
        "sent": int(lag.size),
        "missed": tally.missed,  # due while their client still waited for an answer; sent as soon as it could
        "late": int((lag > LATE_MS).sum()), "late_after_ms": LATE_MS,
        "send_lag_ms": _percentiles(lag) if lag.size else None,
        "unsent_at_end": tally.unsent,  # due before the end, never sent
    }


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
    open_loop = cfg.rate > 0
    return {
        "url": cfg.url,
        "world": world,
        "config": {**asdict(cfg), "api_key": "(set)" if cfg.api_key else None},  # never the key itself
        "elapsed_s": elapsed_s,
        "requests": tally.count,
        "throughput_rps": tally.answered / elapsed_s if elapsed_s > 0 else 0.0,  # answered, not failed
        "schedule": schedule_summary(cfg, tally),
        "edits": latency_summary(tally.edit_ms, elapsed_s, tally.edit_service_ms if open_loop else None),
        "reads": latency_summary(tally.read_ms, elapsed_s, tally.read_service_ms if open_loop else None),
        # an edit and its min_version read, their latencies summed
        "round_trips": latency_summary(tally.round_trip_ms, elapsed_s,
                                       tally.round_trip_service_ms if open_loop else None),
        "edit_timeline": edit_timeline(tally),
        "errors": {"count": error_count, "by_code": dict(sorted(tally.errors.items())),
                   "first_message": dict(sorted(tally.error_messages.items()))},
        # The load generator's own cost: if it nears the time a request takes, it measures itself.
        "client_cpu_us_per_request": tally.cpu_s / tally.count * 1e6 if tally.count else None,
        # Its own garbage collector: what was frozen before the run, and full collections during it.
        "client_gc": {"frozen_objects": tally.frozen_objects, "full_collections": tally.full_collections,
                      "longest_full_collection_ms": tally.longest_collection_s * 1e3},
    }


def _schedule_lines(schedule: dict) -> list[str]:
    if schedule["loop"] == "closed":
        return ["  closed loop (no --rate): each client sends its next request when the last is answered, "
                "latency from the send"]
    lines = [f"  open loop at {schedule['rate_per_s']:g}/s: latency from when each request was due, "
             "service time from when it left"]
    lag = schedule["send_lag_ms"]
    if lag is not None:
        lines.append(f"  left late (> {schedule['late_after_ms']:g} ms): {schedule['late']} of {schedule['sent']}, "
                     f"{schedule['missed']} due while their client still waited; send lag p50 {lag['p50']:.2f} ms  "
                     f"p99 {lag['p99']:.2f} ms  max {lag['max']:.2f} ms; never sent: {schedule['unsent_at_end']}")
    return lines


def _percentile_cells(lat: dict) -> str:
    return (f"p50 {lat['p50']:.2f} ms  p95 {lat['p95']:.2f} ms  p99 {lat['p99']:.2f} ms  "
            f"max {lat['max']:.2f} ms")


def format_report(result: dict) -> str:
    lines = [f"{result['requests']} requests in {result['elapsed_s']:.2f} s: "
             f"{result['throughput_rps']:.1f} requests/s, {result['errors']['count']} errors"]
    lines += _schedule_lines(result["schedule"])
    for kind in ("edits", "reads", "round_trips"):
        s = result.get(kind)
        if s and s["count"]:
            name = "edit+read" if kind == "round_trips" else kind
            lines.append(f"  {name:9s} {s['count']:8d}  {s['throughput_per_s']:9.1f}/s  "
                         f"{_percentile_cells(s['latency_ms'])}")
            if "service_time_ms" in s:
                lines.append(f"  {'service time':>31s}  {_percentile_cells(s['service_time_ms'])}")
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
