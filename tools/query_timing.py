"""Time collision and navigation queries (engine/query.py) on one device: 100,000 points, 10,000
spheres and 10,000 rays against a 256^3 world of each metric, on the engine thread's own path
(checks, upload, one launch, download), and the same requests through a running server over HTTP
(msgpack blobs) when --url is given.

    python tools/query_timing.py [--device nvidia] [--url http://127.0.0.1:8000] [--reps 30]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from sdfserver.edits import parse_edits
from sdfserver.engine.query import run_query
from sdfserver.gpu import GpuContext, choose_device
from sdfserver.world import World, WorldConfig

SIZE = (256, 256, 256)
COUNTS = {"points": 100_000, "spheres": 10_000, "rays": 10_000}


def rows(kind: str, rng: np.random.Generator, voxel_size: float) -> np.ndarray:
    n = COUNTS[kind]
    p = rng.uniform(0, 1, (n, 3)) * np.array(SIZE) * voxel_size
    if kind == "points":
        return p.astype(np.float32)
    if kind == "spheres":
        return np.column_stack([p, rng.uniform(0, 4, n)]).astype(np.float32)
    return np.column_stack([p, rng.normal(size=(n, 3)), np.full(n, 200.0)]).astype(np.float32)


def scene() -> list[dict]:
    return [{"op": "box", "min": [0, 0, 0], "max": [256, 40, 256], "colour": 3},
            *({"op": "sphere", "center": [32 + 48 * i, 90, 32 + 48 * j], "radius": 20.5, "colour": 9}
              for i in range(5) for j in range(5))]


def median_ms(fn, reps: int) -> float:
    fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default=None, help="a device name fragment (default: the first usable)")
    ap.add_argument("--url", default=None, help="also time through this server")
    ap.add_argument("--reps", type=int, default=30)
    args = ap.parse_args()
    gpu = GpuContext(choose_device(args.device))
    rng = np.random.default_rng(1)
    print(f"device: {gpu.device.name.strip()}")
    print("| metric | kind | rows | engine path ms (median) |\n| --- | --- | --- | --- |")
    for metric in ("manhattan", "euclidean"):
        world = World(gpu, WorldConfig(SIZE, 32, 32, metric=metric, voxel_size=0.5))
        try:
            world.apply_edits(parse_edits(scene()))
            world.recompute()
            for kind in COUNTS:
                data = rows(kind, rng, 0.5)
                ms = median_ms(lambda: run_query(world, kind, data), args.reps)
                print(f"| {metric} | {kind} | {len(data)} | {ms:.3f} |")
        finally:
            world.release()
    if args.url:
        import httpx

        from sdfserver import wire
        http = httpx.Client(base_url=args.url, timeout=60)
        print("\n| metric | kind | rows | HTTP round trip ms (median) |\n| --- | --- | --- | --- |")
        for metric in ("manhattan", "euclidean"):
            wid = http.post("/v1/worlds", json={"size": list(SIZE), "chunk_size": 32, "max_distance": 32,
                                                "metric": metric, "voxel_size": 0.5}).json()["id"]
            r = http.post(f"/v1/worlds/{wid}/edits", json={"edits": scene()})
            version = r.json()["version"]
            headers = {"content-type": wire.CONTENT_TYPE, "accept": wire.CONTENT_TYPE}
            for kind in COUNTS:
                body = wire.encode({kind: rows(kind, rng, 0.5)})

                def ask() -> None:
                    answer = http.post(f"/v1/worlds/{wid}/query?min_version={version}", content=body, headers=headers)
                    assert answer.status_code == 200, answer.text
                ms = median_ms(ask, args.reps)
                print(f"| {metric} | {kind} | {COUNTS[kind]} | {ms:.3f} |")
            http.delete(f"/v1/worlds/{wid}")


if __name__ == "__main__":
    main()
