"""Where an edit batch's time goes inside the engine process, for ``engine_drive.py --trace``.

``install(path)`` wraps, in the process that will fork the engine, the points an edit batch
passes: the service taking the request from the input thread (``EngineService._apply``), each
engine step's start and the end of its apply phase (``Engine.step``, ``BatchPipeline.run``), the
reply being handed to the output side (``EngineService._reply``) and the output thread encoding
the batch it sends (``transport.encoded``). The engine process writes what it saw to ``path`` when it
stops. ``summarize(path)`` splits each batch's time in the engine process into: waiting
for a step to take it, the step's apply phase, from there to its acknowledgement (the rest of
the step, the log's sync), and from the acknowledgement to the output thread sending it.
Nothing here runs unless a tool installs it.
"""

from __future__ import annotations

import bisect
import json
import sys
import time

import numpy as np


def wrap(owner, name, before=None, after=None) -> None:
    """Replace ``owner.name`` by a call that runs ``before(*args)`` and ``after(*args)`` around it."""
    original = getattr(owner, name)

    def wrapper(*args, **kwargs):
        if before:
            before(*args)
        result = original(*args, **kwargs)
        if after:
            after(*args)
        return result

    setattr(owner, name, wrapper)


def record_sends(owner, records: list, clock) -> None:
    """Append (API process, request id, time) to ``records`` for each answer the output thread
    encodes (``owner.framed``, or ``encoded`` in older builds; the API process is the output
    thread's loop variable)."""
    name = "framed" if hasattr(owner, "framed") else "encoded"  # older builds: encoded()
    original = getattr(owner, name)

    def encoded(items, *rest, **options):  # rest: a frame's size limit, where the build has one
        now = clock()
        client = sys._getframe(1).f_locals.get("client", b"").decode()
        records.extend((client, item.id, now) for item in items if hasattr(item, "id"))
        return original(items, *rest, **options)

    setattr(owner, name, encoded)


def install(path: str) -> None:
    from sdfserver.engine import proc, transport
    from sdfserver.engine.batches import BatchPipeline
    from sdfserver.engine.core import Engine
    from sdfserver.engine.service import EngineService

    seen: dict[str, list] = {"received": [], "steps": [], "applied": [], "answered": [], "sent": []}
    clock = time.perf_counter

    # request ids are each API process's own: a batch is known by (its API process, its id)
    wrap(EngineService, "_apply", before=lambda self, client, m: seen["received"].append(
        (client.decode(), m.id, clock())))
    wrap(Engine, "step", before=lambda self: seen["steps"].append(clock()))
    wrap(BatchPipeline, "run", after=lambda self, batches, *_: seen["applied"].append((clock(), len(batches))))
    wrap(EngineService, "_reply", before=lambda self, client, request_id, *_, **__: seen["answered"].append(
        (client.decode(), request_id, clock())))
    record_sends(transport, seen["sent"], clock)
    original_serve = proc.serve_engine

    def serve_engine(*args, **kwargs):
        try:
            return original_serve(*args, **kwargs)
        finally:  # the engine stopped (SIGTERM): what it saw, written once
            with open(path, "w") as out:
                json.dump({k: list(v) for k, v in seen.items()}, out)

    proc.serve_engine = serve_engine


def summarize(path: str, since_s: float = 0.0, start: float | None = None) -> dict:
    """Medians and p90s (ms) of each part of an edit batch's time in the engine process, for
    the batches received ``since_s`` after the first one, or from ``start`` (``time.perf_counter``,
    which is the same clock in every process of a Linux machine) on."""
    seen = json.load(open(path))
    steps = sorted(seen["steps"])
    applied = sorted(t for t, _ in seen["applied"])
    answered = {(c, i): t for c, i, t in seen["answered"]}
    sent = {(c, i): t for c, i, t in seen["sent"]}
    if start is None:
        start = seen["received"][0][2] + since_s if seen["received"] else 0.0
    parts: dict[str, list[float]] = {"wait for a step": [], "apply phase": [], "to acknowledgement": [],
                                     "to the output thread's send": [], "in the engine process": []}
    for client, request_id, received in seen["received"]:
        request_id = (client, request_id)
        if received < start or request_id not in sent or request_id not in answered:
            continue
        k = bisect.bisect_left(steps, received)
        if k >= len(steps):
            continue
        step = steps[k]
        a = bisect.bisect_left(applied, step)
        if a >= len(applied):
            continue
        parts["wait for a step"].append(step - received)
        parts["apply phase"].append(applied[a] - step)
        parts["to acknowledgement"].append(answered[request_id] - applied[a])
        parts["to the output thread's send"].append(sent[request_id] - answered[request_id])
        parts["in the engine process"].append(sent[request_id] - received)

    def ms(values: list[float], q: float) -> float:
        return round(float(np.percentile(values, q)) * 1e3, 3) if values else float("nan")

    return {name: {"p50_ms": ms(v, 50), "p90_ms": ms(v, 90), "n": len(v)} for name, v in parts.items()}


if __name__ == "__main__":
    print(json.dumps(summarize(sys.argv[1], start=float(sys.argv[2]) if len(sys.argv) > 2 else None), indent=1))
