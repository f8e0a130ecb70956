"""Load test: N simulated game clients painting random brushes into one world.

Each game client loops: post one edit batch of random brushes (spheres and
boxes, placing and deleting, random positions and brush sizes from a seed —
the dissertation's benchmark mode, §3.5), and after every ``--read-every``-th
edit read the field around it with ``min_version`` set to the version the edit
returned (read-your-writes). Requests go out as fast as possible or at a set
total ``--rate``; the run stops at ``--duration`` seconds or after
``--requests`` requests, whichever comes first (both are bounded).

    python clients/loadtest.py --url http://127.0.0.1:8000 --clients 64 --duration 30 --json out.json

Against a server with API keys, set ``SDFSERVER_API_KEY`` (or ``--api-key``); a
``429`` counts as a ``rate_limited`` error and the client waits its Retry-After.

Reports throughput, p50/p95/p99 latency and errors per request kind, and for
``--read-every`` runs the round trip (an edit's latency plus its read's: brush
edit to field ready, read-your-writes); prints a
progress line once a second (to stderr); ``--json`` writes everything. Exits 1
when any request failed. Latency is measured from the moment a request is
sent to its answer; with ``--rate`` a client that falls behind sends at once.
With ``--processes P`` the clients are spread over P processes (one Python
process tops out at a few thousand requests per second).

Each game client holds one connection. With ``--http lean`` (the default) it is
a ``sdfclient.lean.LeanConnection``, hand-written HTTP/1.1 on an asyncio protocol,
so that the load generator costs little next to the server it measures;
``--http httpx`` uses ``AsyncClient`` instead. The report says what the load
generator itself cost: its processes' CPU time per request
(``client_cpu_us_per_request``).
"""

from __future__ import annotations

import argparse
import array
import asyncio
import contextlib
import functools
import json
import multiprocessing
import os
import queue
import random
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Coroutine, TypeVar

sys.path.insert(0, str(Path(__file__).resolve().parent))

import httpx  # noqa: E402

from loadtest_report import ProgressLine, format_report, latency_summary, report  # noqa: E402,F401
from sdfclient import AsyncClient, Client, RateLimited, SdfClientError, ServerError, edits  # noqa: E402
from sdfclient.lean import LeanConnection  # noqa: E402
from sdfclient.stream import Stream  # noqa: E402

T = TypeVar("T")
MAX_DURATION_S = 3600.0


@dataclass(frozen=True)
class LoadConfig:
    url: str
    world_id: str = ""
    world_size: tuple[int, int, int] = (64, 64, 64)
    clients: int = 4
    duration_s: float = 10.0
    requests: int = 0  # 0: no count limit (the duration still bounds the run)
    rate: float = 0.0  # total requests per second; 0: as fast as possible
    read_every: int = 1  # read the field after every k-th edit; 0: never
    read_size: int = 16  # side of the box read around an edit; 0: the whole world
    read_format: str = "distance"
    ops_per_batch: int = 1
    brush_min: float = 1.0
    brush_max: float = 8.0
    delete_fraction: float = 0.25
    sphere_fraction: float = 0.5
    seed: int = 0
    timeout_s: float = 30.0
    edits_over: str = "http"  # http: POST /edits; ws: the WebSocket stream (reads stay HTTP)
    http: str = "lean"  # lean: LeanConnection; httpx: AsyncClient
    loop: str = "uvloop"  # the generator's event loop: uvloop (when installed) or asyncio
    api_key: str | None = field(default=None, repr=False)  # sent as a bearer token; never reported


# -- the brushes --------------------------------------------------------------------------------


class Brushes:
    """Random brush batches from one seeded generator."""

    def __init__(self, seed: int, cfg: LoadConfig):
        self.rng = random.Random(seed)
        self.cfg = cfg

    def batch(self) -> tuple[list[dict], tuple[int, int, int]]:
        ops, center = [], (0, 0, 0)
        for _ in range(self.cfg.ops_per_batch):
            op, center = self.brush()
            ops.append(op)
        return ops, center

    def brush(self) -> tuple[dict, tuple[int, int, int]]:
        rng, cfg = self.rng, self.cfg
        center = tuple(rng.randrange(s) for s in cfg.world_size)
        colour = 0 if rng.random() < cfg.delete_fraction else rng.randrange(1, 256)
        if rng.random() < cfg.sphere_fraction:
            return edits.sphere(center, rng.uniform(cfg.brush_min, cfg.brush_max), colour), center
        half = [max(1, round(rng.uniform(cfg.brush_min, cfg.brush_max))) for _ in range(3)]
        lo = [max(0, c - h) for c, h in zip(center, half)]
        hi = [min(s, c + h) for c, h, s in zip(center, half, cfg.world_size)]
        return edits.box(lo, hi, colour), center

    def read_box(self, center: tuple[int, int, int]):
        if self.cfg.read_size <= 0:
            return None
        side = self.cfg.read_size
        lo = [min(max(0, c - side // 2), max(0, s - side)) for c, s in zip(center, self.cfg.world_size)]
        return lo, [min(s, l + side) for l, s in zip(lo, self.cfg.world_size)]


# -- one worker: a set of game clients in one event loop --------------------------------------------


@dataclass
class Tally:
    edit_ms: array.array = field(default_factory=lambda: array.array("d"))
    edit_at_s: array.array = field(default_factory=lambda: array.array("d"))  # when each edit was sent
    read_ms: array.array = field(default_factory=lambda: array.array("d"))
    round_trip_ms: array.array = field(default_factory=lambda: array.array("d"))  # edit + its read
    errors: dict[str, int] = field(default_factory=dict)
    cpu_s: float = 0.0  # the load generator's own CPU time (time.process_time) over the run

    @property
    def count(self) -> int:
        return len(self.edit_ms) + len(self.read_ms) + sum(self.errors.values())

    def error(self, exc: Exception) -> None:
        key = exc.code if isinstance(exc, ServerError) else type(exc).__name__
        self.errors[key] = self.errors.get(key, 0) + 1

    def merge(self, other: "Tally") -> None:
        """Add a worker's tally to this one."""
        for name in ("edit_ms", "edit_at_s", "read_ms", "round_trip_ms"):
            getattr(self, name).extend(getattr(other, name))
        for key, n in other.errors.items():
            self.errors[key] = self.errors.get(key, 0) + n
        self.cpu_s += other.cpu_s


class Budget:
    """Request tickets shared by the clients of one worker, and the deadline."""

    def __init__(self, requests: int, deadline: float):
        self.left = requests if requests > 0 else None
        self.deadline = deadline

    def take(self) -> bool:
        if time.perf_counter() >= self.deadline:
            return False
        if self.left is None:
            return True
        if self.left <= 0:
            return False
        self.left -= 1
        return True


async def game_client(index: int, cfg: LoadConfig, tally: Tally, budget: Budget, start: float) -> None:
    brushes = Brushes(cfg.seed * 1_000_003 + index, cfg)
    interval = cfg.clients / cfg.rate if cfg.rate > 0 else 0.0
    next_at = start + interval * index / cfg.clients
    edits_sent = 0
    async with contextlib.AsyncExitStack() as stack:
        if cfg.http == "lean":
            client = LeanConnection(cfg.url, api_key=cfg.api_key, timeout=cfg.timeout_s)
        else:
            client = AsyncClient(cfg.url, api_key=cfg.api_key, timeout=cfg.timeout_s,
                                 limits=httpx.Limits(max_connections=1))
        await stack.enter_async_context(client)
        if cfg.edits_over == "ws":  # what AsyncClient.stream opens, whichever HTTP client reads
            stream = await stack.enter_async_context(Stream.connect(cfg.url, cfg.world_id, api_key=cfg.api_key))
            edit = stream.edit
        else:
            edit = functools.partial(client.edit, cfg.world_id)
        # LeanConnection's timeout bounds the whole exchange; httpx's are per phase, the stream has none.
        if cfg.http == "lean" and cfg.edits_over == "http":
            send_edit = edit
        else:
            def send_edit(batch: list[dict]):
                return asyncio.wait_for(edit(batch), cfg.timeout_s)
        pending_read = None
        while True:
            if interval:
                delay = next_at - time.perf_counter()
                if delay > 0:
                    await asyncio.sleep(delay)
                next_at = max(next_at + interval, time.perf_counter() - interval)
            if not budget.take():
                return
            t0 = time.perf_counter()
            try:
                if pending_read is not None:
                    box, version, edit_ms = pending_read
                    pending_read = None
                    block = await client.read_field(cfg.world_id, box, format=cfg.read_format,
                                                    min_version=version)
                    if block.version < version:
                        tally.errors["stale_read"] = tally.errors.get("stale_read", 0) + 1
                        continue
                    read_ms = (time.perf_counter() - t0) * 1e3
                    tally.read_ms.append(read_ms)
                    tally.round_trip_ms.append(edit_ms + read_ms)
                    continue
                batch, center = brushes.batch()
                version = await send_edit(batch)
                edit_ms = (time.perf_counter() - t0) * 1e3
                tally.edit_ms.append(edit_ms)
                tally.edit_at_s.append(t0 - start)
                edits_sent += 1
                if cfg.read_every and edits_sent % cfg.read_every == 0:
                    pending_read = (brushes.read_box(center), version, edit_ms)
            except (SdfClientError, TimeoutError) as exc:
                tally.error(exc)
                if isinstance(exc, RateLimited):  # a well-behaved game client waits as told
                    pause = exc.retry_after_s if exc.retry_after_s is not None else 1.0
                    await asyncio.sleep(max(0.0, min(pause, budget.deadline - time.perf_counter())))


async def run_clients(cfg: LoadConfig, indices: list[int], requests: int, tally: Tally,
                      progress=None) -> float:
    cpu_start = time.process_time()
    start = time.perf_counter()
    budget = Budget(requests, start + cfg.duration_s)
    tasks = [asyncio.create_task(game_client(i, cfg, tally, budget, start)) for i in indices]
    while not all(t.done() for t in tasks):
        await asyncio.wait(tasks, timeout=0.25)
        if progress is not None:
            progress(tally)
    for t in tasks:
        t.result()  # a bug in the load test itself surfaces here
    tally.cpu_s += time.process_time() - cpu_start
    return time.perf_counter() - start


def event_loop_kind(wanted: str) -> str:
    """uvloop when asked for and installed (``uvicorn[standard]`` brings it), else asyncio."""
    if wanted == "uvloop":
        try:
            import uvloop  # noqa: F401
        except ImportError:
            return "asyncio"
    return wanted


def run_loop(cfg: LoadConfig, coroutine: Coroutine[Any, Any, T]) -> T:
    """Run ``coroutine`` on the configured loop: the generator's own CPU per request is part of
    every latency it measures, and uvloop spends less of it."""
    if event_loop_kind(cfg.loop) == "asyncio":
        return asyncio.run(coroutine)
    import uvloop
    with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
        return runner.run(coroutine)


def _worker(cfg: LoadConfig, indices: list[int], requests: int, out: "multiprocessing.Queue",
            go: "multiprocessing.Event") -> None:
    tally = Tally()
    last = [0.0]

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


# -- the command line ---------------------------------------------------------------------------------


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--url", default="http://127.0.0.1:8000", help="the server's base URL")
    ap.add_argument("--api-key", default=None,
                    help="the server's API key, sent as a bearer token (default: $SDFSERVER_API_KEY; the "
                         "variable keeps it out of the process list)")
    ap.add_argument("--world", default="", help="use this world id instead of creating one")
    ap.add_argument("--size", type=int, nargs=3, default=(64, 64, 64), metavar=("SX", "SY", "SZ"),
                    help="size of the world created for the run")
    ap.add_argument("--chunk-size", type=int, default=16)
    ap.add_argument("--max-distance", type=int, default=255)
    ap.add_argument("--algorithm", default="exact")
    ap.add_argument("--keep-world", action="store_true", help="do not delete the world created for the run")
    ap.add_argument("--clients", type=int, default=4, help="simulated game clients")
    ap.add_argument("--processes", type=int, default=1, help="spread the clients over this many processes")
    ap.add_argument("--duration", type=float, default=10.0, help=f"seconds, at most {MAX_DURATION_S:g}")
    ap.add_argument("--requests", type=int, default=0, help="stop after this many requests (0: duration only)")
    ap.add_argument("--rate", type=float, default=0.0, help="total requests/s (0: as fast as possible)")
    ap.add_argument("--read-every", type=int, default=1, help="read the field after every k-th edit (0: never)")
    ap.add_argument("--read-size", type=int, default=16, help="side of the box read (0: the whole world)")
    ap.add_argument("--read-format", choices=("distance", "packed"), default="distance")
    ap.add_argument("--edits-over", choices=("http", "ws"), default="http",
                    help="post edits over HTTP or send them over each client's WebSocket stream")
    ap.add_argument("--http", choices=("lean", "httpx"), default="lean",
                    help="each client's HTTP connection: sdfclient.lean.LeanConnection (little client CPU) "
                         "or sdfclient.AsyncClient (httpx)")
    ap.add_argument("--loop", choices=("uvloop", "asyncio"), default="uvloop",
                    help="the load generator's event loop (uvloop falls back to asyncio when not installed)")
    ap.add_argument("--ops-per-batch", type=int, default=1, help="brushes per edit batch")
    ap.add_argument("--brush-min", type=float, default=1.0, help="smallest brush radius / half-side, voxels")
    ap.add_argument("--brush-max", type=float, default=8.0, help="largest brush radius / half-side, voxels")
    ap.add_argument("--delete-fraction", type=float, default=0.25, help="share of brushes that erase")
    ap.add_argument("--sphere-fraction", type=float, default=0.5, help="share of brushes that are spheres")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=30.0, help="per-request timeout, seconds")
    ap.add_argument("--json", type=Path, help="write the full results here")
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    args = ap.parse_args(argv)
    if not 0 < args.duration <= MAX_DURATION_S:
        ap.error(f"--duration must be in (0, {MAX_DURATION_S:g}]")
    for name in ("clients", "processes", "ops_per_batch"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be at least 1")
    for name in ("requests", "rate", "read_every", "read_size"):
        if getattr(args, name) < 0:
            ap.error(f"--{name.replace('_', '-')} must not be negative")
    if not 0 <= args.brush_min <= args.brush_max:
        ap.error("need 0 <= --brush-min <= --brush-max")
    if args.api_key is None:
        args.api_key = os.environ.get("SDFSERVER_API_KEY") or None
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    created = not args.world
    try:
        with Client(args.url, api_key=args.api_key, timeout=args.timeout) as client:
            info = (client.create_world(args.size, chunk_size=args.chunk_size, max_distance=args.max_distance,
                                        algorithm=args.algorithm)
                    if created else client.get_world(args.world))
    except SdfClientError as exc:
        print(f"loadtest: cannot {'create' if created else 'open'} the world at {args.url}: {exc}",
              file=sys.stderr)
        return 2
    cfg = LoadConfig(
        url=args.url, world_id=info.id, world_size=info.size, clients=args.clients,
        duration_s=args.duration, requests=args.requests, rate=args.rate, read_every=args.read_every,
        read_size=args.read_size, read_format=args.read_format, ops_per_batch=args.ops_per_batch,
        brush_min=args.brush_min, brush_max=args.brush_max, delete_fraction=args.delete_fraction,
        sphere_fraction=args.sphere_fraction, seed=args.seed, timeout_s=args.timeout,
        edits_over=args.edits_over, http=args.http, loop=event_loop_kind(args.loop), api_key=args.api_key,
    )
    try:
        tally, elapsed = drive(cfg, args.processes, show_progress=not args.quiet)
    finally:
        if created and not args.keep_world:
            with Client(args.url, api_key=args.api_key, timeout=args.timeout) as client:
                try:
                    client.delete_world(info.id)
                except SdfClientError as exc:
                    print(f"loadtest: could not delete world {info.id}: {exc}", file=sys.stderr)
    world = {"id": info.id, "size": list(info.size), "chunk_size": info.chunk_size,
             "max_distance": info.max_distance, "algorithm": info.algorithm, "created": created}
    result = report(cfg, tally, elapsed, world)
    print(format_report(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 1 if result["errors"]["count"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
