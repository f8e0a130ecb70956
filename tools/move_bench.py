"""Moves under load: a server with two engines (``--devices D,D`` or two Ray engine actors), worlds
written to by many clients, one world moved back and forth between the engines. Reports each
move's time, the writers' latencies (all worlds, and the moved world alone), and checks that
every world's acknowledged versions are exactly 1..version (nothing lost, nothing doubled).

    python3 tools/move_bench.py --device nvidia --size 256 --worlds 8 --writers 16 --moves 10 \
        --json $OUT/moves.json
    python3 tools/move_bench.py --device 0 --size 32 --worlds 2 --writers 2 --moves 2   # CPU smoke
    python3 tools/move_bench.py --cluster --device nvidia ...   # two Ray engine actors, 0.5 GPU each
    python3 tools/move_bench.py --devices 0,1 ...   # one engine process on each of two GPUs
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import threading
import time
import uuid
from pathlib import Path

import httpx
import numpy as np

from serve_build import serve_build  # tools/ is sys.path[0]

ROOT = Path(__file__).resolve().parents[1]


def brush(rng: np.random.Generator, size: int) -> list[dict]:
    return [{"op": "sphere", "center": [float(v) for v in rng.uniform(8, size - 8, 3)],
             "radius": float(rng.uniform(2, 6)), "colour": int(rng.integers(0, 256))}]


def percentile(values: list[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 3) if values else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="nvidia")
    parser.add_argument("--devices", default=None,
                        help="the two engines' devices, as serve --devices (default: --device twice)")
    parser.add_argument("--cluster", action="store_true", help="two Ray engine actors instead of engine processes")
    parser.add_argument("--engine-gpus", type=float, default=0.5)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--worlds", type=int, default=8)
    parser.add_argument("--fill", type=int, default=200, help="batches written to each world before the run")
    parser.add_argument("--writers", type=int, default=16)
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--pause", type=float, default=1.0, help="seconds between moves")
    parser.add_argument("--workers", type=int, default=4)
    parser.add_argument("--port", type=int, default=8771)
    parser.add_argument("--json", default=None)
    parser.add_argument("--log-dir", default=os.environ.get("OUT", tempfile.gettempdir()))
    args = parser.parse_args()
    args.url = f"http://127.0.0.1:{args.port}"
    engines = (["--cluster", "local", "--engines", "2", "--engine-gpus", str(args.engine_gpus), "--device", args.device]
               if args.cluster else ["--devices", args.devices or f"{args.device},{args.device}"])
    data_dir = tempfile.mkdtemp(prefix="sdf-move-bench-")
    os.makedirs(args.log_dir, exist_ok=True)
    try:
        with serve_build(ROOT, os.path.join(args.log_dir, "move-bench-server.log"), args.port, data_dir,
                         ["--workers", str(args.workers), "--no-warm-up", *engines], device=None, ready_s=300):
            report = run(args)
    finally:
        shutil.rmtree(data_dir, ignore_errors=True)
    print(json.dumps(report, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)


def run(args: argparse.Namespace) -> dict:
    http = httpx.Client(base_url=args.url, timeout=120)
    size = args.size
    worlds = []
    for _ in range(args.worlds):
        r = http.post("/v1/worlds", json={"size": [size] * 3, "chunk_size": 16, "max_distance": 31})
        r.raise_for_status()
        worlds.append(r.json()["id"])
    rng = np.random.default_rng(1)
    for world in worlds:
        for _ in range(args.fill):
            http.post(f"/v1/worlds/{world}/edits", json={"edits": brush(rng, size)}).raise_for_status()
    moved = worlds[0]
    lock = threading.Lock()
    acknowledged: dict[str, list[int]] = {w: [] for w in worlds}
    latency: dict[str, list[float]] = {"all": [], "moved": []}
    retries = {"count": 0}
    stop = threading.Event()

    def writer(index: int) -> None:
        local = np.random.default_rng(100 + index)
        world = worlds[index % len(worlds)]
        with httpx.Client(base_url=args.url, timeout=120) as client:
            while not stop.is_set():
                body, key = {"edits": brush(local, size)}, uuid.uuid4().hex
                started = time.perf_counter()
                while True:
                    r = client.post(f"/v1/worlds/{world}/edits", json=body, headers={"idempotency-key": key})
                    if r.status_code == 200:
                        break
                    if r.status_code != 503:
                        raise SystemExit(f"edit answered {r.status_code}: {r.text}")
                    with lock:
                        retries["count"] += 1
                    time.sleep(0.005)
                ms = (time.perf_counter() - started) * 1e3
                with lock:
                    acknowledged[world].append(r.json()["version"])
                    latency["all"].append(ms)
                    if world == moved:
                        latency["moved"].append(ms)

    threads = [threading.Thread(target=writer, args=(i,), daemon=True) for i in range(args.writers)]
    began = time.perf_counter()
    for t in threads:
        t.start()
    moves = []
    engine = http.get(f"/v1/worlds/{moved}").json()["engine"]
    for _ in range(args.moves):
        time.sleep(args.pause)
        started = time.perf_counter()
        r = http.post(f"/v1/worlds/{moved}/move", json={"engine": 1 - engine})
        if r.status_code != 200:
            raise SystemExit(f"move answered {r.status_code}: {r.text}")
        moves.append((time.perf_counter() - started) * 1e3)
        engine = 1 - engine
    time.sleep(args.pause)
    stop.set()
    for t in threads:
        t.join(120)
    elapsed = time.perf_counter() - began
    lost = doubled = 0
    for world, versions in acknowledged.items():
        final = http.get(f"/v1/worlds/{world}").json()["version"]
        seen = set(versions)
        doubled += len(versions) - len(seen)
        lost += len(set(range(args.fill + 1, final + 1)) - seen)
    statuses = http.get("/v1/engines").json()
    return {
        "device": statuses[0]["device"], "engines": len(statuses), "cluster": args.cluster,
        "world_side": size, "worlds": args.worlds, "writers": args.writers, "fill_batches": args.fill,
        "moves": len(moves), "move_ms": [round(m, 1) for m in moves], "move_ms_p50": percentile(moves, 50),
        "move_ms_max": round(max(moves), 1) if moves else None,
        "batches": len(latency["all"]), "batches_per_s": round(len(latency["all"]) / elapsed, 1),
        "write_ms_p50": percentile(latency["all"], 50), "write_ms_p99": percentile(latency["all"], 99),
        "moved_world_write_ms_p50": percentile(latency["moved"], 50),
        "moved_world_write_ms_p99": percentile(latency["moved"], 99),
        "moved_world_write_ms_max": round(max(latency["moved"]), 1) if latency["moved"] else None,
        "retries_503": retries["count"], "lost": lost, "doubled": doubled,
    }


if __name__ == "__main__":
    main()
