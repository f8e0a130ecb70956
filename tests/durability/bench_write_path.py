"""The write path's cost: edit batches/s and latency with the log synced (fdatasync, group commit)
against syncing off, in one run, against real servers on loopback.

    PYTHONPATH=. python tests/durability/bench_write_path.py [--clients 32] [--seconds 8]

Each client posts one small batch (a 2x2x2 box) at a time to one of four 32^3 worlds and waits
for its acknowledgement, so latency is the full round trip. Not collected by pytest.
"""

from __future__ import annotations

import argparse
import asyncio
import shutil
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent)]  # durable_server and the server_process it uses
from durable_server import ServerProcess  # noqa: E402


async def load(url: str, worlds: list[str], clients: int, seconds: float) -> tuple[int, np.ndarray, int]:
    latencies: list[float] = []
    errors = 0
    stop = time.perf_counter() + seconds

    async def client(i: int) -> None:
        nonlocal errors
        rng = np.random.default_rng(i)
        async with httpx.AsyncClient(base_url=url, timeout=30) as http:
            while time.perf_counter() < stop:
                lo = [int(v) for v in rng.integers(0, 30, 3)]
                body = {"edits": [{"op": "box", "min": lo, "max": [v + 2 for v in lo],
                                   "colour": int(rng.integers(0, 256))}]}
                t = time.perf_counter()
                r = await http.post(f"/v1/worlds/{worlds[i % len(worlds)]}/edits", json=body)
                latencies.append(time.perf_counter() - t)
                errors += r.status_code != 200

    await asyncio.gather(*(client(i) for i in range(clients)))
    return len(latencies), np.array(latencies) * 1e3, errors


def run(sync: bool, clients: int, seconds: float) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="sdf-bench-"))
    server = ServerProcess(tmp / "data", "--sync" if sync else "--no-sync", "--warm-up").wait_ready()
    try:
        worlds = [server.http.post("/v1/worlds", json={"size": [32, 32, 32], "chunk_size": 8,
                                                        "max_distance": 8}).json()["id"] for _ in range(4)]
        asyncio.run(load(server.url, worlds, clients, 1.0))  # warm up
        count, ms, errors = asyncio.run(load(server.url, worlds, clients, seconds))
    finally:
        server.stop()
        shutil.rmtree(tmp)
    return {"sync": sync, "batches": count, "per_s": count / seconds, "p50": float(np.percentile(ms, 50)),
            "p99": float(np.percentile(ms, 99)), "errors": errors}


def run_storage(sync: bool, threads: int, seconds: float) -> dict:
    """The log alone (no server, no device): threads appending to four worlds' logs."""
    import threading

    from sdfserver.storage import Storage

    tmp = Path(tempfile.mkdtemp(prefix="sdf-bench-log-"))
    storage = Storage(tmp, sync=sync)
    stores = [storage.create_world(f"w{i}", {"config": {}}) for i in range(4)]
    locks = [threading.Lock() for _ in stores]
    latencies: list[list[float]] = [[] for _ in range(threads)]
    stop = time.perf_counter() + seconds
    payload = [{"op": "box", "min": [1, 2, 3], "max": [3, 4, 5], "colour": 7}]

    def worker(i: int) -> None:
        store, lock = stores[i % 4], locks[i % 4]
        while time.perf_counter() < stop:
            t = time.perf_counter()
            with lock:
                future = store.append(store.last_version + 1, payload)
            future.result()
            latencies[i].append(time.perf_counter() - t)

    workers = [threading.Thread(target=worker, args=(i,)) for i in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    syncs = storage.committer.syncs
    for store in stores:
        store.close()
    storage.close()
    shutil.rmtree(tmp)
    ms = np.concatenate([np.array(x) for x in latencies]) * 1e3
    return {"per_s": len(ms) / seconds, "p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99)),
            "per_sync": len(ms) / syncs if syncs else float("nan")}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clients", type=int, default=32)
    p.add_argument("--seconds", type=float, default=8.0)
    args = p.parse_args()
    print(f"{args.clients} clients, 4 worlds of 32^3, one 2x2x2 box per batch, {args.seconds:g} s each")
    print("| log sync | batches/s | p50 ms | p99 ms | errors |\n| --- | --- | --- | --- | --- |")
    for sync in (True, False):
        r = run(sync, args.clients, args.seconds)
        print(f"| {'on (fdatasync, group commit)' if sync else 'off'} | {r['per_s']:.0f} | {r['p50']:.2f} | "
              f"{r['p99']:.2f} | {r['errors']} |", flush=True)
    print(f"\nThe log alone: {args.clients} threads appending to 4 worlds' logs, {args.seconds:g} s each")
    print("| log sync | appends/s | p50 ms | p99 ms | records per fdatasync |\n| --- | --- | --- | --- | --- |")
    for sync in (True, False):
        r = run_storage(sync, args.clients, args.seconds)
        print(f"| {'on' if sync else 'off'} | {r['per_s']:.0f} | {r['p50']:.3f} | {r['p99']:.3f} | "
              f"{r['per_sync']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
