"""Where one request's time goes inside the server: ``sdfserver serve`` with timing hooks.

Runs the server in this process (same flags as ``sdfserver serve``) with timestamps taken at the
hand-offs of the hot path — uvicorn receiving the request's bytes, the fast lane's start and end
(event loop), ``Engine.submit``, the engine step and a read's device copy, the log's hand-over (append_many), its write and
``fdatasync``, the future's completion and the event loop resuming — and, when it stops
(Ctrl-C or SIGTERM), prints the median of each gap for edits and reads:

    python tools/request_timeline.py --device nvidia --port 8765 --data-dir /tmp/tl &
    python clients/loadtest --url http://127.0.0.1:8765 --clients 1 --duration 10 \\
        --size 256 256 256 --read-every 1 --read-size 16 --quiet
    kill %1

Meant for one client (with many, requests overlap and the gaps mix). The hooks cost a few
microseconds each; compare gaps, not totals, with a run without them.
"""

from __future__ import annotations

import functools
import inspect
import os
import signal
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sdfserver.api import fastlane, server  # noqa: E402
from sdfserver.engine import core  # noqa: E402
from sdfserver import world  # noqa: E402
from sdfserver.storage import wal  # noqa: E402

EVENTS: list[tuple[int, str]] = []  # (perf_counter_ns, tag); list.append is atomic under the GIL


def mark(tag: str) -> None:
    EVENTS.append((time.perf_counter_ns(), tag))


def hook(owner: object, name: str, tag: str) -> None:
    real = getattr(owner, name, None)
    if real is None:
        return
    if inspect.iscoroutinefunction(real):
        async def timed(*args, **kwargs):
            mark(tag + ">")
            try:
                return await real(*args, **kwargs)
            finally:
                mark(tag + "<")
    else:
        def timed(*args, **kwargs):
            mark(tag + ">")
            try:
                return real(*args, **kwargs)
            finally:
                mark(tag + "<")
    setattr(owner, name, functools.wraps(real)(timed))


def install() -> None:
    from uvicorn.protocols.http import httptools_impl

    hook(httptools_impl.HttpToolsProtocol, "data_received", "recv")  # the request's bytes arrive
    hook(fastlane.FastLane, "__call__", "lane")
    hook(world.World, "read_field", "read")
    hook(core.Engine, "step", "step")
    hook(core.Engine, "call", "call")
    hook(wal.WorldLog, "append_many", "hand-over")
    hook(os, "write", "write")  # the log's record writes
    hook(os, "fdatasync", "fdatasync")
    submit = core.Engine.submit

    def timed_submit(self, command):
        kind = type(command).__name__
        mark("submit")
        future = submit(self, command)
        future.add_done_callback(lambda _: mark("done " + kind))
        return future

    core.Engine.submit = timed_submit


GAPS = [("recv>", "lane>"), ("lane>", "submit"), ("submit", "step>"), ("step>", "read>"), ("read>", "read<"),
        ("step>", "step<"), ("submit", "hand-over<"), ("hand-over>", "write>"),
        ("hand-over>", "fdatasync>"), ("fdatasync>", "fdatasync<"), ("submit", "done"), ("done", "call<"),
        ("call<", "lane<"), ("lane>", "lane<"), ("recv>", "lane<")]


def summary() -> str:
    requests: list[dict[str, float]] = []
    for t, tag in EVENTS:
        if tag == "recv>":
            requests.append({})
        name = tag.split(" ")[0]
        if requests and (not name.endswith("<") or name[:-1] + ">" in requests[-1]):  # an end after its start
            requests[-1].setdefault(name, t / 1e3)
            if tag.startswith("done "):
                requests[-1]["kind"] = tag.split(" ", 1)[1]
    lines = []
    for kind in ("ApplyEdits", "Read", "Query"):
        group = [r for r in requests if r.get("kind") == kind and "lane<" in r]
        if not group:
            continue
        lines.append(f"{kind}: {len(group)} requests, median gap in us")
        for a, b in GAPS:
            gaps = [r[b] - r[a] for r in group if a in r and b in r]
            if gaps:
                lines.append(f"  {a:>12} .. {b:<12} {statistics.median(gaps):9.1f}")
    return "\n".join(lines)


def main() -> int:
    install()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        return server.main(sys.argv[1:])
    finally:
        print(summary(), file=sys.stderr)


if __name__ == "__main__":
    raise SystemExit(main())
