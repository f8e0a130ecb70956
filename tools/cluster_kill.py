"""Kill one engine of a running cluster server under load: the time until its worlds serve
again, and what the other engines' clients saw meanwhile.

    python tools/cluster_kill.py --url http://127.0.0.1:8767 --worlds 10 --side 256 --json kill.json

Creates ``--worlds`` worlds per engine (placement spreads them), writes 20 batches into each,
starts one writer thread per world (a sphere per batch, the same batch with the same
``Idempotency-Key`` again after a failed attempt), SIGKILLs the engine holding the first world, and reports: seconds until every one of
its worlds answers a field read at its last acknowledged version; the survivors' edit latencies
(p50, p99, max) and failures during the outage; batches acknowledged; and whether each world's
version equals its acknowledged batches (a retried batch applied twice shows as a higher version).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import threading
import time

import httpx
import numpy as np


def writer(url: str, world: str, side: int, stop: threading.Event, log: list, acked: list) -> None:
    rng = np.random.default_rng()
    with httpx.Client(base_url=url, timeout=60) as http:
        while not stop.is_set():
            batch = [{"op": "sphere", "center": rng.uniform(0, side, 3).tolist(), "radius": 4.0,
                      "colour": int(rng.integers(0, 256))}]
            key = {"idempotency-key": f"{world}-{len(acked)}-{rng.integers(1 << 60)}"}
            while not stop.is_set():
                started = time.monotonic()
                try:
                    ok = http.post(f"/v1/worlds/{world}/edits", json={"edits": batch}, headers=key).status_code == 200
                except httpx.TransportError:
                    ok = False
                log.append((started, time.monotonic() - started, ok))
                if ok:
                    acked.append(1)
                    break
                time.sleep(0.05)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--url", default="http://127.0.0.1:8767")
    parser.add_argument("--worlds", type=int, default=10, help="worlds per engine")
    parser.add_argument("--side", type=int, default=256)
    parser.add_argument("--json", default="")
    args = parser.parse_args()
    http = httpx.Client(base_url=args.url, timeout=120)
    engines = len(http.get("/v1/engines").json())
    worlds = [http.post("/v1/worlds", json={"size": [args.side] * 3, "chunk_size": 32}).json()["id"]
              for _ in range(args.worlds * engines)]
    for w in worlds:
        for i in range(20):
            http.post(f"/v1/worlds/{w}/edits", json={"edits": [{"op": "sphere", "center": [i * 7 % args.side, 40, 60],
                                                                "radius": 6, "colour": 1 + i}]})
    listed = http.get("/v1/engines").json()
    victim = next(e for e in listed if worlds[0] in e["world_ids"])
    stop = threading.Event()
    logs = {w: [] for w in worlds}
    acked = {w: [] for w in worlds}
    threads = [threading.Thread(target=writer, args=(args.url, w, args.side, stop, logs[w], acked[w]))
               for w in worlds]
    for t in threads:
        t.start()
    time.sleep(3)
    killed = time.monotonic()
    os.kill(victim["pid"], signal.SIGKILL)
    waiting = set(victim["world_ids"])
    while waiting and time.monotonic() - killed < 120:
        for w in list(waiting):
            try:
                r = http.get(f"/v1/worlds/{w}/field", params={"min": "0,0,0", "max": "1,1,1"}, timeout=2)
                if r.status_code == 200:
                    waiting.discard(w)
            except httpx.TransportError:
                pass
        time.sleep(0.02)
    back = time.monotonic() - killed
    time.sleep(2)
    stop.set()
    for t in threads:
        t.join(timeout=60)
    during = [(d, ok) for w in worlds if w not in victim["world_ids"]
              for (t0, d, ok) in logs[w] if killed <= t0 <= killed + back]
    latencies = sorted(d * 1e3 for d, ok in during if ok)
    versions = {w: http.get(f"/v1/worlds/{w}").json()["version"] for w in worlds}
    doubled = sum(versions[w] - 20 - len(acked[w]) for w in worlds)
    result = {
        "engines": engines, "worlds": len(worlds), "side": args.side, "killed_engine": victim["engine"],
        "its_worlds": len(victim["world_ids"]), "serving_again_s": round(back, 2), "not_back": sorted(waiting),
        "others_during_outage": {
            "edits": len(latencies), "failed": sum(1 for _, ok in during if not ok),
            "p50_ms": round(float(np.percentile(latencies, 50)), 2) if latencies else None,
            "p99_ms": round(float(np.percentile(latencies, 99)), 2) if latencies else None,
            "max_ms": round(latencies[-1], 2) if latencies else None},
        "acknowledged": sum(len(a) for a in acked.values()),
        "applied_beyond_acknowledged": doubled,
    }
    print(json.dumps(result))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f)


if __name__ == "__main__":
    main()
