"""Where one large query's time goes, hop by hop, across the client, an API process and the engine.

``python3 tools/query_timeline.py [--device intel] [--size 64] [--points 100000] [--reps 60]``
starts ``sdfserver serve`` (one API process, no log) with timestamps installed in the launcher
before it forks (as ``request_timeline.py`` does), then one client on a plain socket sends the
same msgpack query (``{"points": blob}``) again and again, each after the last was answered,
and prints, for every point a request passes, its median time after the client began sending
(the first time it was passed and, for points passed several times, such as socket reads, the
last time and how many times). ``--kind spheres`` asks 10,000 spheres instead; ``--no-trace``
times round trips alone; ``--httpx`` sends with httpx (``query_timing.py``'s client) instead;
``--server-tree`` serves another checkout (an A/B).

The points, in the order a request meets them: the client's send; the API process's ASGI call,
its body read, the msgpack decode, the rows unpacked, the request message encoded and written;
the engine's input thread fed each piece of the frame, decoding it, handing it to the service;
the engine thread's query; the reply queued (the answer's arrays made message fields); the
answer encoded and sent by the output thread; the API process fed each piece of the answer's
frame, decoding it, converting the result; the response encoded and handed to uvicorn; the
client's first and last byte of the response. The server's own ``Server-Timing`` header, where
it has one, is reported beside the client's round trip.

Every process reads ``time.perf_counter`` (CLOCK_MONOTONIC on Linux, one clock for all of them).
A lone client has one request in the server at a time, so a point belongs to the request whose
round trip holds it.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

from serve_build import serve_build  # tools/ is sys.path[0]

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
COUNTS = {"points": 100_000, "spheres": 10_000}


def install(directory: str) -> None:
    """Wrap the points a query passes, in this process and every process it forks; each process
    writes ``<directory>/<pid>.json`` as it stops."""
    from sdfserver import wire
    from sdfserver.api import engine_client, hot, routes
    from sdfserver.engine import frames, proc, reads, transport
    from sdfserver.engine import messages as msg
    from sdfserver.engine.service import EngineService

    events: list[tuple[str, float]] = []
    clock = time.perf_counter
    role = ["launcher"]

    def mark(name):
        return lambda *_, **__: events.append((f"{role[0]}: {name}", clock()))

    def wrap(owner, name, before=None, after=None):
        original = getattr(owner, name)

        def wrapper(*args, **kwargs):
            if before:
                before()
            result = original(*args, **kwargs)
            if after:
                after()
            return result

        setattr(owner, name, wrapper)

    def wrap_async(owner, name, before=None, after=None):
        original = getattr(owner, name)

        async def wrapper(*args, **kwargs):
            if before:
                before()
            result = await original(*args, **kwargs)
            if after:
                after()
            return result

        setattr(owner, name, wrapper)

    # the API process
    original_call = hot.HotRoutes.__call__

    async def call(self, scope, receive, send):
        events.append(("api: ASGI call", clock()))

        async def sending(message):
            events.append((f"api: ASGI send {message['type']}", clock()))
            await send(message)

        await original_call(self, scope, receive, sending)
        events.append(("api: ASGI call returned", clock()))

    hot.HotRoutes.__call__ = call
    import sdfserver.api.bodies as bodies
    wrap_async(routes, "query_response", before=mark("route start"))
    wrap_async(bodies, "read_body", after=mark("body read"))
    wrap(wire, "decode", after=mark("msgpack decoded"))
    wrap(routes, "query_rows", after=mark("rows unpacked"))
    wrap(engine_client.EngineClient, "_send", before=mark("request encode+write start"),
         after=mark("request written"))
    wrap(frames.FrameReader, "feed", before=mark("frame reader fed"))
    wrap(engine_client.EngineClient, "_arrived", before=mark("answer frame whole"))
    wrap(engine_client.BaseClient, "_take", before=mark("answer decoded"))
    wrap(msg, "decode_result", after=mark("result converted"))
    wrap(wire, "encode", before=mark("response encode start"), after=mark("response encoded"))

    # the engine process
    class Decoder:  # msgspec's decoder is a C type: its method cannot be wrapped in place
        def __init__(self, inner):
            self.inner = inner

        def decode(self, data):
            events.append((f"{role[0]}: request decode start", clock()))
            try:
                return self.inner.decode(data)
            finally:
                events.append((f"{role[0]}: request decoded", clock()))

    msg.REQUEST_DECODER = Decoder(msg.REQUEST_DECODER)
    wrap(EngineService, "handle", after=mark("handed to the engine"))
    wrap(reads, "run_query", before=mark("run_query start"), after=mark("run_query end"))
    wrap(EngineService, "_reply", before=mark("reply converted"), after=mark("reply queued"))
    wrap(transport, "framed" if hasattr(transport, "framed") else "encoded", before=mark("answer encode start"),
         after=mark("answer encoded"))
    wrap(transport.EngineTransport, "_deliver", after=mark("answer send call returned"))
    wrap(transport.EngineTransport, "_flush", after=mark("answer backlog flushed"))

    def dump():
        if events:
            with open(os.path.join(directory, f"{os.getpid()}.json"), "w") as out:
                json.dump(events, out)

    os.register_at_fork(after_in_child=events.clear)
    original_engine, original_stop = proc.serve_engine, engine_client.EngineClient.stop

    def serve_engine(*args, **kwargs):
        role[0] = "engine"
        try:
            return original_engine(*args, **kwargs)
        finally:
            dump()

    async def stop(self):
        dump()
        return await original_stop(self)

    role_api = engine_client.EngineClient.start

    async def start(self):
        role[0] = "api"
        return await role_api(self)

    proc.serve_engine, engine_client.EngineClient.stop = serve_engine, stop
    engine_client.EngineClient.start = start


class PlainClient:
    """HTTP/1.1 on one kept-alive socket: the whole request in one write, the response read into
    one buffer of its length (so the client's own cost is the least it can be)."""

    def __init__(self, port: int):
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def post(self, path: str, body: bytes, content_type: str) -> tuple[dict[str, str], bytes, list[float]]:
        head = (f"POST {path} HTTP/1.1\r\nhost: 127.0.0.1\r\ncontent-type: {content_type}\r\n"
                f"accept: {content_type}\r\ncontent-length: {len(body)}\r\n\r\n").encode()
        t0 = time.perf_counter()
        self.sock.sendall(head + body)
        t1 = time.perf_counter()
        data = b""
        while b"\r\n\r\n" not in data:
            piece = self.sock.recv(65536)
            if not piece:
                raise ConnectionError("the server closed the connection")
            data += piece
        t2 = time.perf_counter()
        head_bytes, _, rest = data.partition(b"\r\n\r\n")
        lines = head_bytes.decode("latin-1").split("\r\n")
        headers = {k.lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
        length = int(headers["content-length"])
        buffer = bytearray(length)
        buffer[:len(rest)] = rest
        got, view = len(rest), memoryview(buffer)
        while got < length:
            n = self.sock.recv_into(view[got:])
            if not n:
                raise ConnectionError("the server closed the connection")
            got += n
        t3 = time.perf_counter()
        return headers | {"status": lines[0]}, bytes(buffer), [t0, t1, t2, t3]


class HttpxClient:
    """The same request through httpx; only the whole round trip is known."""

    def __init__(self, url: str):
        import httpx

        self.http = httpx.Client(base_url=url, timeout=60)

    def post(self, path: str, body: bytes, content_type: str) -> tuple[dict[str, str], bytes, list[float]]:
        t0 = time.perf_counter()
        r = self.http.post(path, content=body, headers={"content-type": content_type, "accept": content_type})
        t3 = time.perf_counter()
        return dict(r.headers) | {"status": f"{r.status_code} {r.reason_phrase}"}, r.content, [t0, t3, t3, t3]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="intel")
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--kind", choices=tuple(COUNTS), default="points")
    parser.add_argument("--reps", type=int, default=60)
    parser.add_argument("--port", type=int, default=8793)
    parser.add_argument("--server-tree", default=str(ROOT), help="another checkout's server (an A/B)")
    parser.add_argument("--no-trace", action="store_true", help="round trips only, no timestamps installed")
    parser.add_argument("--httpx", action="store_true", help="the client is httpx (as query_timing.py's) instead of "
                        "a plain socket: its round trip holds httpx's reading of the answer")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from sdfserver import wire

    directory = tempfile.mkdtemp(prefix="sdfserver-qtimeline-")
    hook = "" if args.no_trace else f"import query_timeline; query_timeline.install({directory!r}); "
    entry = ["-c", f"import sys; sys.path.insert(0, {str(HERE)!r}); {hook}"
                   "from sdfserver.api.server import main; raise SystemExit(main())"]
    url = f"http://127.0.0.1:{args.port}"
    rounds: list[list[float]] = []
    server_ms: list[float] = []
    with serve_build(args.server_tree, os.path.join(directory, "server.log"), args.port,
                     tempfile.mkdtemp(prefix="sdfserver-qtimeline-data-"), ["--workers", "1", "--no-persist"],
                     device=args.device, entry=entry, ready_s=240):
        config = {"size": [args.size] * 3, "voxel_size": 0.5}
        request = urllib.request.Request(url + "/v1/worlds", method="POST", data=json.dumps(config).encode(),
                                         headers={"content-type": "application/json"})
        world = json.load(urllib.request.urlopen(request))["id"]
        rng = np.random.default_rng(1)
        n = COUNTS[args.kind]
        p = rng.uniform(0, args.size * 0.5, (n, 3))
        rows = p if args.kind == "points" else np.column_stack([p, rng.uniform(0, 4, n)])
        body = wire.encode({args.kind: rows.astype(np.float32)})
        client = HttpxClient(url) if args.httpx else PlainClient(args.port)
        for i in range(args.reps + 5):
            headers, answer, stamps = client.post(f"/v1/worlds/{world}/query", body, wire.CONTENT_TYPE)
            assert headers["status"].endswith("200 OK"), (headers, answer[:200])
            if i >= 5:
                rounds.append(stamps)
                timing = headers.get("server-timing", "")
                if "dur=" in timing:
                    server_ms.append(float(timing.split("dur=")[1].split(",")[0].split(";")[0]))
    whole = [(r[3] - r[0]) * 1e3 for r in rounds]
    print(f"{args.kind}: {COUNTS[args.kind]} rows, {len(body)} bytes sent, {len(answer)} bytes answered; "
          f"round trip median {statistics.median(whole):.2f} ms (min {min(whole):.2f}, n {len(whole)})"
          + (f"; Server-Timing app median {statistics.median(server_ms):.2f} ms" if server_ms else ""))
    if args.no_trace:
        return 0
    events: list[tuple[str, float]] = []
    for path in Path(directory).glob("[0-9]*.json"):
        events.extend(tuple(e) for e in json.load(open(path)))
    events.sort(key=lambda e: e[1])
    first: dict[str, list[float]] = {}
    last: dict[str, list[float]] = {}
    count: dict[str, list[int]] = {}
    times = [e[1] for e in events]
    import bisect
    for t0, t1, t2, t3 in rounds:
        seen: dict[str, list[float]] = {}
        for name, at in events[bisect.bisect_left(times, t0):bisect.bisect_right(times, t3)]:
            seen.setdefault(name, []).append((at - t0) * 1e3)
        for name, ats in seen.items():
            first.setdefault(name, []).append(ats[0])
            last.setdefault(name, []).append(ats[-1])
            count.setdefault(name, []).append(len(ats))
        for name, at in (("client: sent", t1 - t0), ("client: response head", t2 - t0),
                         ("client: response whole", t3 - t0)):
            first.setdefault(name, []).append(at * 1e3)
    spans = [b - a for a, b in zip(first.get("api: route start", []), first.get("api: response encoded", []))]
    if spans and len(spans) == len(first.get("api: route start", [])):
        print("route start -> response encoded (what Server-Timing measures), traced: "
              f"median {statistics.median(spans):.2f} ms")
    print("| point | first (ms, median) | last (ms, median) | times passed (median) |\n| --- | --- | --- | --- |")
    for name in sorted(first, key=lambda k: statistics.median(first[k])):
        lasts = last.get(name)
        passes = statistics.median(count[name]) if name in count else 1
        tail = f"{statistics.median(lasts):.3f}" if lasts and passes > 1 else ""
        print(f"| {name} | {statistics.median(first[name]):.3f} | {tail} | {passes:g} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
