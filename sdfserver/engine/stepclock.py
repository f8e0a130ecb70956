"""How long an engine step took, phase by phase, and what the engine thread did meanwhile:
counted in the engine's metrics, and logged with its phases when the step was slow — at most
one line every ``SLOW_STEP_LOG_INTERVAL_S``, which counts the slow steps left out since the
line before: on a slow device nearly every step is slow, and a line each would bury the log."""

from __future__ import annotations

import logging
import math
import resource
import threading
import time
from typing import Callable, Iterable

from sdfserver.engine.commands import StepReport
from sdfserver.engine.metrics import EngineMetrics

log = logging.getLogger("sdfserver.engine")
SLOW_STEP_LOG_INTERVAL_S = 10.0


class SlowStepLog:
    """Lets one slow step's line through every ``interval_s``; counts the others."""

    def __init__(self, interval_s: float = SLOW_STEP_LOG_INTERVAL_S, clock: Callable[[], float] = time.monotonic):
        self.interval_s, self.clock = interval_s, clock
        self._lock = threading.Lock()  # engines of one process (tests) share it
        self._last = -math.inf
        self._left_out, self._slowest_ms = 0, 0.0

    def admit(self, step_ms: float) -> tuple[int, float] | None:
        """None if this step's line is left out; else (slow steps left out since the last line,
        the slowest of them in ms)."""
        with self._lock:
            now = self.clock()
            if now - self._last < self.interval_s:
                self._left_out += 1
                self._slowest_ms = max(self._slowest_ms, step_ms)
                return None
            admitted = (self._left_out, self._slowest_ms)
            self._last, self._left_out, self._slowest_ms = now, 0, 0.0
            return admitted


slow_steps = SlowStepLog()


class StepClock:
    """Started at the top of a step (on the engine thread); ``lap`` ends a phase."""

    def __init__(self, report: StepReport):
        self.report = report
        self.started = self._last = time.perf_counter()
        self._cpu = time.thread_time()
        self._usage = resource.getrusage(resource.RUSAGE_THREAD)
        # what the step does now, read by other threads (/readyz, /metrics): the phase and the
        # worlds it works on, as one tuple so that a reader sees both of one moment
        self.current: tuple[str, Iterable[str]] = ("", ())

    def doing(self, phase: str, worlds: Iterable[str] = ()) -> None:
        """The step starts ``phase`` on ``worlds`` (a collection the step no longer changes)."""
        self.current = (phase, worlds)

    def busy(self, budget_ms: float) -> dict | None:
        """What the step does, when it has run ``budget_ms`` or longer (any thread); else None."""
        elapsed_ms = (time.perf_counter() - self.started) * 1e3
        if elapsed_ms < budget_ms:
            return None
        phase, worlds = self.current
        return {"busy_ms": round(elapsed_ms, 1), "phase": phase, "worlds": sorted(set(worlds))}

    def lap(self, phase: str) -> None:
        now = time.perf_counter()
        self.report.phases_ms[phase] = (now - self._last) * 1e3
        self._last = now

    def stop(self, metrics: EngineMetrics, slow_step_ms: float) -> None:
        """Count the step; log it if it took ``slow_step_ms`` or more (up to the last lap)."""
        report, seconds = self.report, self._last - self.started
        report.cpu_ms = (time.thread_time() - self._cpu) * 1e3
        # The kernel splits user from system time by sampling at ticks, so over one step the
        # split is rough; cpu_ms (time.thread_time) is the exact total.
        usage = resource.getrusage(resource.RUSAGE_THREAD)
        report.user_ms = (usage.ru_utime - self._usage.ru_utime) * 1e3
        report.system_ms = (usage.ru_stime - self._usage.ru_stime) * 1e3
        report.page_faults = usage.ru_minflt - self._usage.ru_minflt + usage.ru_majflt - self._usage.ru_majflt
        report.preempted = usage.ru_nivcsw - self._usage.ru_nivcsw
        metrics.steps.inc()
        metrics.step_seconds.observe(seconds)
        for phase, ms in report.phases_ms.items():
            metrics.phase(phase).inc(ms / 1e3)
        admitted = slow_steps.admit(seconds * 1e3) if seconds * 1e3 >= slow_step_ms else None
        if admitted is None:
            return
        left_out, slowest_ms = admitted
        phases = ", ".join(f"{k} {v:.1f}" for k, v in report.phases_ms.items())
        phases += " (" + ", ".join(f"{k} {v:.1f}" for k, v in report.apply_ms.items()) + " of apply)"
        since = (f"; {left_out} more slow steps (the slowest {slowest_ms:.1f} ms) since the last such line"
                 if left_out else "")
        log.warning("slow engine step: %.1f ms, %.1f ms of it on a CPU (%.1f user, %.1f system; %d page "
                    "faults, %d preemptions) (%s), %d batches%s", seconds * 1e3, report.cpu_ms, report.user_ms,
                    report.system_ms, report.page_faults, report.preempted, phases, report.applied_batches, since)
