"""The game clients in this process or spread over several, their tallies merged."""

from __future__ import annotations

import multiprocessing
import os
import queue
import time

from loadtest.collector import settle
from loadtest.config import LoadConfig
from loadtest.game import Tally, run_clients, run_loop
from loadtest.report import ProgressLine


def _worker(cfg: LoadConfig, indices: list[int], requests: int, out: "multiprocessing.Queue",
            go: "multiprocessing.Event") -> None:
    tally = Tally()
    last = [0.0]
    tally.frozen_objects = settle()

    def progress(t: Tally) -> None:
        now = time.perf_counter()
        if now - last[0] >= 0.25:
            last[0] = now
            out.put(("progress", os.getpid(), t.count, sum(t.errors.values())))

    out.put(("ready", os.getpid()))
    go.wait()  # every worker has imported everything: start together
    elapsed = run_loop(cfg, run_clients(cfg, indices, requests, tally, progress))
    out.put(("done", os.getpid(), tally, elapsed))


# -- driving and reporting --------------------------------------------------------------------------


def _shares(total: int, parts: int) -> list[int]:
    return [total // parts + (1 if i < total % parts else 0) for i in range(parts)]


def drive(cfg: LoadConfig, processes: int = 1, show_progress: bool = True) -> tuple[Tally, float]:
    """Run the game clients (in this process or spread over ``processes``); merged tallies."""
    line = ProgressLine(show_progress, cfg.requests, cfg.duration_s)
    processes = max(1, min(processes, cfg.clients))
    if processes == 1:
        tally = Tally()
        tally.frozen_objects = settle()
        elapsed = run_loop(cfg, run_clients(
            cfg, list(range(cfg.clients)), cfg.requests, tally,
            lambda t: line.update(t.count, sum(t.errors.values()))))
        line.update(tally.count, sum(tally.errors.values()), force=True)
        line.finish()
        return tally, elapsed
    ctx = multiprocessing.get_context("spawn")
    out = ctx.Queue()
    groups = [list(range(cfg.clients))[p::processes] for p in range(processes)]
    shares = _shares(cfg.requests, processes) if cfg.requests else [0] * processes
    go = ctx.Event()
    workers = [ctx.Process(target=_worker, args=(cfg, g, n, out, go), daemon=True)
               for g, n in zip(groups, shares)]
    for w in workers:
        w.start()
    counts: dict[int, tuple[int, int]] = {}
    tally, done, ready, elapsed = Tally(), 0, 0, 0.0
    hard_stop = time.perf_counter() + cfg.duration_s + cfg.timeout_s + 120.0
    while done < len(workers):
        try:
            message = out.get(timeout=0.25)
        except queue.Empty:
            failed = [w.exitcode for w in workers if w.exitcode not in (None, 0)]
            if failed or time.perf_counter() > hard_stop or not any(w.is_alive() for w in workers):
                for w in workers:
                    if w.is_alive():
                        w.terminate()
                raise RuntimeError(f"a load-test worker died (exit codes {failed}) or did not finish") from None
            message = None
        if message and message[0] == "ready":
            ready += 1
            if ready == len(workers):
                line.start = line.last = time.perf_counter()
                go.set()
        elif message and message[0] == "progress":
            counts[message[1]] = (message[2], message[3])
        elif message and message[0] == "done":
            done += 1
            tally.merge(message[2])
            counts[message[1]] = (0, 0)
            elapsed = max(elapsed, message[3])
        line.update(tally.count + sum(c for c, _ in counts.values()),
                    sum(tally.errors.values()) + sum(e for _, e in counts.values()))
    for w in workers:
        w.join()
    line.update(tally.count, sum(tally.errors.values()), force=True)
    line.finish()
    return tally, elapsed
