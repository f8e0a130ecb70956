"""Hostile clients against a running server, and whether it keeps serving others meanwhile.

Opens ``--slow`` connections that trickle a header that never ends (slowloris) and one that
sends a ``--header-mib`` header as fast as the server takes it, while a well-behaved client
asks ``/livez`` every 0.2 s; reports the server's memory (the launcher and its children),
the good client's latencies, and how many hostile sockets the server closed and when.

    sdfserver serve --port 8765 &
    python tools/hostile_probe.py --url http://127.0.0.1:8765 --pid $! --slow 1000 --header-mib 256
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import sys
import threading
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from server_process import tree_rss_bytes  # noqa: E402


def good_client(url: str, stop: threading.Event, latencies: list[float], failures: list[str]) -> None:
    while not stop.is_set():
        started = time.perf_counter()
        try:
            with urllib.request.urlopen(url + "/livez", timeout=5) as answer:
                answer.read()
            latencies.append((time.perf_counter() - started) * 1e3)
        except OSError as exc:
            failures.append(str(exc))
        stop.wait(0.2)


def big_header(host: str, port: int, mib: int, result: dict) -> None:
    sock = socket.create_connection((host, port))
    sock.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\nx-big: ")
    sent, chunk = 0, b"a" * (1 << 16)
    started = time.monotonic()
    try:
        while sent < mib << 20:
            sock.sendall(chunk)
            sent += len(chunk)
    except OSError as exc:
        result["stopped_by"] = type(exc).__name__
    sock.settimeout(2)
    try:
        result["answer"] = sock.recv(200).split(b"\r\n", 1)[0].decode(errors="replace")
    except OSError:
        result["answer"] = ""
    result.update(sent_mib=round(sent / (1 << 20), 1), seconds=round(time.monotonic() - started, 2))
    sock.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--url", default="http://127.0.0.1:8765")
    parser.add_argument("--pid", type=int, required=True, help="the server's (launcher's) process id")
    parser.add_argument("--slow", type=int, default=1000, help="slowloris connections")
    parser.add_argument("--header-mib", type=int, default=256, help="size of the one huge header")
    parser.add_argument("--seconds", type=float, default=20.0, help="how long to watch")
    parser.add_argument("--json", default="")
    args = parser.parse_args()
    host, port = args.url.split("//")[1].split(":")
    port = int(port)
    rss_before = tree_rss_bytes(args.pid)
    stop, latencies, failures = threading.Event(), [], []
    watcher = threading.Thread(target=good_client, args=(args.url, stop, latencies, failures))
    watcher.start()
    slow, refused = [], 0
    for _ in range(args.slow):
        try:
            sock = socket.create_connection((host, port), timeout=5)
            sock.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\nx-slow: a")
            sock.setblocking(False)
            slow.append([sock, None])
        except OSError:
            refused += 1
    big: dict = {}
    bigger = threading.Thread(target=big_header, args=(host, port, args.header_mib, big))
    bigger.start()
    started, peak = time.monotonic(), rss_before
    while time.monotonic() - started < args.seconds:
        peak = max(peak, tree_rss_bytes(args.pid))
        for entry in slow:
            if entry[1] is not None:
                continue
            try:
                entry[0].send(b"a")  # one byte a second: the header never ends
                data = entry[0].recv(200)
                if data == b"" or data.startswith(b"HTTP/1.1"):
                    entry[1] = (time.monotonic() - started, data.split(b"\r\n", 1)[0].decode(errors="replace"))
            except BlockingIOError:
                pass
            except OSError as exc:
                entry[1] = (time.monotonic() - started, type(exc).__name__)
        time.sleep(1.0)
    stop.set()
    watcher.join()
    bigger.join(timeout=30)
    closed = [e[1] for e in slow if e[1] is not None]
    for entry in slow:
        entry[0].close()
    report = {
        "slow_connections": len(slow), "refused_at_connect": refused,
        "slow_closed": len(closed),
        "slow_closed_after_s": round(statistics.median(c[0] for c in closed), 1) if closed else None,
        "slow_answers": sorted({c[1] for c in closed}),
        "big_header": big,
        "rss_mib": {"before": round(rss_before / 2**20), "peak": round(peak / 2**20),
                    "after": round(tree_rss_bytes(args.pid) / 2**20)},
        "good_client": {"requests": len(latencies), "failures": len(failures),
                        "p50_ms": round(statistics.median(latencies), 2) if latencies else None,
                        "max_ms": round(max(latencies), 2) if latencies else None},
    }
    print(json.dumps(report, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
