"""Where a lone client's request spends its time, hop by hop, across the load generator, an API
process and the engine process.

``python3 tools/request_timeline.py [--device nvidia] [--size 256] [--duration 6] [-- serve flags]``
starts ``sdfserver serve`` with timestamps installed (in the launcher, before it forks the
engine and API processes, as ``engine_trace.py`` does), runs one game client (an edit, then a
field read of 16³ at its version) and prints, per request kind, the median and p90 of each hop:

  client → API process        the load generator's send to the API process's ASGI call
  API → engine input          the API process's ZeroMQ send to the engine's input thread handing
                              it to the service
  in the engine               to the service's reply (the step, the log's sync, the read)
  engine reply → output send  the reply waiting for the output thread
  output send → API           the ZeroMQ hop back and the API process's loop waking
  API answer                  from the reply to the ASGI response sent
  API → client                the response to the load generator having parsed it

Then, per request kind, when the engine passed each point of its step (``install_engine_steps``),
counted from the engine taking the request: the request submitted, the step's start, planning,
the log written and handed to the committer, the sync and the check after it, the brushes
launched, the recompute, a read, the step's end.

Every process reads ``time.perf_counter`` (CLOCK_MONOTONIC on Linux, one clock for all of them).
Each timestamp costs a list append; the records are written when the server stops (SIGTERM).
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import json
import os
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

from engine_trace import record_sends, wrap
from serve_build import serve_build

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def install(directory: str) -> None:
    """Wrap the points a request passes, in this process and every process it forks; the engine
    and each API process write ``<directory>/<pid>.json`` as they stop."""
    from sdfserver.api import engine_client
    from sdfserver.api.hot import HotRoutes
    from sdfserver.engine import proc

    try:  # where the output thread's encoding lives (proc.py in builds before transport.py)
        from sdfserver.engine import transport
    except ImportError:
        transport = proc
    from sdfserver.engine.service import EngineService

    seen: dict[str, list] = {"asgi_in": [], "asgi_out": [], "api_send": [], "api_take": [],
                             "engine_in": [], "engine_reply": [], "engine_send": [], "engine_steps": []}
    clock = time.perf_counter
    install_engine_steps(seen["engine_steps"], clock)

    def dump(*_):
        if any(seen.values()):
            with open(os.path.join(directory, f"{os.getpid()}.json"), "w") as out:
                json.dump(seen, out)

    original_call = HotRoutes.__call__

    async def call(self, scope, receive, send):
        seen["asgi_in"].append((scope.get("method"), clock()))
        try:
            await original_call(self, scope, receive, send)
        finally:
            seen["asgi_out"].append((scope.get("method"), clock()))

    HotRoutes.__call__ = call
    wrap(engine_client.EngineClient, "_send", before=lambda self, request: seen["api_send"].append(
        (self.identity.decode(), request.id, type(request).__name__, clock())))

    def took(self, outputs):
        now, identity = clock(), getattr(self, "identity", b"").decode()
        seen["api_take"].extend((identity, item.id, now) for item in outputs.items if hasattr(item, "id"))

    wrap(engine_client.BaseClient, "_take", before=took)
    wrap(EngineService, "handle", before=lambda self, client, request: seen["engine_in"].append(
        (client.decode(), request.id, clock())))
    wrap(EngineService, "_reply", before=lambda self, client, request_id, *_: seen["engine_reply"].append(
        (client.decode(), request_id, clock())))
    record_sends(transport, seen["engine_send"], clock)

    os.register_at_fork(after_in_child=lambda: [records.clear() for records in seen.values()])
    original_engine, original_stop = proc.serve_engine, engine_client.EngineClient.stop

    def serve_engine(*args, **kwargs):
        try:
            return original_engine(*args, **kwargs)
        finally:  # the engine stopped (SIGTERM)
            dump()

    async def stop(self):
        dump()  # the API process's shutdown
        return await original_stop(self)

    proc.serve_engine, engine_client.EngineClient.stop = serve_engine, stop


def install_engine_steps(events: list, clock) -> None:
    """Record (point, time) as the engine process passes the points of a step: the request
    submitted, the step's start, each batch planned, the log written and handed to the committer, the sync, the check after it,
    the brushes launched, the recompute, the publishing, a read, the step's end. A lone client
    has one request in the engine at a time, so each point belongs to the request whose engine
    span holds it."""
    from sdfserver.engine.batches import BatchPipeline
    from sdfserver.engine.core import Engine
    from sdfserver.engine.reads import Reads
    from sdfserver.engine.service import EngineService
    from sdfserver.engine.subscriptions import Subscriptions
    from sdfserver.storage.committer import Committer
    from sdfserver.storage.journal import StorageJournal
    from sdfserver.world import World

    def mark(name):
        return lambda *_: events.append((name, clock()))

    wrap(EngineService, "handle", after=mark("submitted"))
    wrap(Engine, "step", before=mark("step start"), after=mark("step end"))
    wrap(BatchPipeline, "plan", after=mark("planned"))
    wrap(StorageJournal, "record_batches", after=mark("log written"))
    wrap(StorageJournal, "start_syncs", after=mark("handed to the committer"))
    wrap(World, "apply_plans", after=mark("brushes launched"))
    wrap(Engine, "_recompute", after=mark("recomputed"))
    wrap(Subscriptions, "publish", after=mark("published"))
    wrap(Reads, "read", before=mark("read start"), after=mark("read end"))
    sync_one = Committer._sync_one

    def timed_sync(item):
        events.append(("sync start", clock()))
        try:
            return sync_one(item)
        finally:
            events.append(("sync end", clock()))

    Committer._sync_one = staticmethod(timed_sync)
    wrap(Committer, "_after_sync", after=mark("checked after the sync"))


async def lone_client(url: str, world: str, size: int, duration_s: float, http: str) -> list[tuple]:
    """(kind, sent, answered) for each request of one client: an edit, then its read."""
    sys.path.insert(0, str(ROOT / "clients"))
    from loadtest.game import LEAN_CLIENTS

    from loadtest.config import Brushes, LoadConfig

    brushes = Brushes(7, LoadConfig(url, world, (size, size, size)))
    done: list[tuple] = []
    async with LEAN_CLIENTS[http](url) as client:
        end = time.perf_counter() + duration_s
        while time.perf_counter() < end:
            batch, center = brushes.batch()
            t0 = time.perf_counter()
            version = await client.edit(world, batch)
            t1 = time.perf_counter()
            await client.read_field(world, brushes.read_box(center), min_version=version)
            t2 = time.perf_counter()
            done += [("POST", t0, t1), ("GET", t1, t2)]
    return done


def timeline(directory: str, requests: list[tuple], skip: int = 50) -> dict:
    records: dict[str, list] = {}
    for path in Path(directory).glob("[0-9]*.json"):
        for key, values in json.load(open(path)).items():
            records.setdefault(key, []).extend(values)
    asgi_in = sorted(records.get("asgi_in", []), key=lambda r: r[1])
    asgi_out = sorted(records.get("asgi_out", []), key=lambda r: r[1])
    sends = sorted(records.get("api_send", []), key=lambda r: r[3])
    by_id = {name: {(c, i): t for c, i, t in records.get(name, [])}
             for name in ("api_take", "engine_in", "engine_reply", "engine_send")}
    steps = sorted(records.get("engine_steps", []), key=lambda r: r[1])
    hops: dict[str, dict[str, list[float]]] = {}
    engine_points: dict[str, dict[str, list[float]]] = {}
    for kind, sent, answered in requests[skip:]:
        inside = lambda rows, at: [r for r in rows if sent <= r[at] <= answered]  # noqa: E731
        came, went, out = inside(asgi_in, 1), inside(asgi_out, 1), inside(sends, 3)
        if len(came) != 1 or len(went) != 1 or len(out) != 1:
            continue
        key = (out[0][0], out[0][1])
        points = [sent, came[0][1], out[0][3], by_id["engine_in"].get(key), by_id["engine_reply"].get(key),
                  by_id["engine_send"].get(key), by_id["api_take"].get(key), went[0][1], answered]
        if None in points:
            continue
        names = ["client → API process", "API process → its send", "API → engine input", "in the engine",
                 "engine reply → output send", "output send → API", "API answer", "API → client"]
        per = hops.setdefault(kind, {name: [] for name in names + ["whole"]})
        for name, a, b in zip(names, points, points[1:]):
            per[name].append(b - a)
        per["whole"].append(answered - sent)
        span = engine_points.setdefault(kind, {})
        for name, at in steps_between(steps, points[3], points[5]):
            span.setdefault(name, []).append(at - points[3])
    figures = {kind: {name: {"p50_us": round(float(np.percentile(v, 50)) * 1e6, 1),
                             "p90_us": round(float(np.percentile(v, 90)) * 1e6, 1), "n": len(v)}
                      for name, v in per.items()} for kind, per in hops.items()}
    for kind, span in engine_points.items():  # each point's time after the engine took the request
        figures.setdefault(kind, {})["engine points"] = {
            name: {"p50_us": round(float(np.percentile(v, 50)) * 1e6, 1), "n": len(v)}
            for name, v in sorted(span.items(), key=lambda item: np.median(item[1]))}
    return figures


def steps_between(steps: list[tuple[str, float]], start: float, end: float) -> list[tuple[str, float]]:
    """The first time each engine point was passed between ``start`` and ``end``."""
    first: dict[str, float] = {}
    for name, at in steps[bisect.bisect_left(steps, start, key=lambda r: r[1]):]:
        if at > end:
            break
        first.setdefault(name, at)
    return list(first.items())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="")
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--duration", type=float, default=6.0)
    parser.add_argument("--port", type=int, default=8767)
    parser.add_argument("--json", help="write the table's figures here too")
    parser.add_argument("--http", choices=("aiohttp", "httptools"), default="aiohttp", help="the client's connection")
    parser.add_argument("--server-tree", default=str(ROOT), help="another checkout's server (an A/B)")
    parser.add_argument("serve_flags", nargs="*", help="more `sdfserver serve` flags (after --)")
    args = parser.parse_args()
    directory = tempfile.mkdtemp(prefix="sdfserver-timeline-")
    entry = ["-c", f"import sys; sys.path.insert(0, {str(HERE)!r}); import request_timeline; "
                   f"request_timeline.install({directory!r}); from sdfserver.api.server import main; raise SystemExit(main())"]
    url = f"http://127.0.0.1:{args.port}"
    with serve_build(args.server_tree, os.path.join(directory, "server.log"), args.port,
                     tempfile.mkdtemp(prefix="sdfserver-timeline-data-"), args.serve_flags, device=args.device,
                     entry=entry, ready_s=240):
        request = urllib.request.Request(url + "/v1/worlds", method="POST", headers={"content-type": "application/json"},
                                         data=json.dumps({"size": [args.size] * 3}).encode())
        world = json.load(urllib.request.urlopen(request))["id"]
        requests = asyncio.run(lone_client(url, world, args.size, args.duration, args.http))
    figures = timeline(directory, requests)
    for kind, per in figures.items():
        points = per.pop("engine points", {})
        print(f"{kind}: " + ", ".join(f"{name} {v['p50_us']:.0f} µs (p90 {v['p90_us']:.0f})" for name, v in per.items()))
        print(f"{kind}, in the engine after it took the request (p50): "
              + ", ".join(f"{name} {v['p50_us']:.0f} µs (n {v['n']})" for name, v in points.items()))
        per["engine points"] = points
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
