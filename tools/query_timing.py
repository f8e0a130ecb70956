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

from sdfserver.algorithms.base import int4
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


def breakdown(world: World, data: np.ndarray, reps: int) -> None:
    """Where one points query's time goes on the engine, and what crossing processes costs."""
    import pyopencl as cl

    from sdfserver.engine import messages as msg
    from sdfserver.engine.query import LOCAL, PLACE, device_rows

    gpu, config, n = world.gpu, world.config, len(data)
    defines, field = world.field_source()
    kernel = gpu.programs.kernel("query.cl", "query_points", **defines)
    inputs = device_rows("points", data, config)
    in_buf = gpu.upload(inputs)
    out_buf = cl.Buffer(gpu.context, cl.mem_flags.WRITE_ONLY, size=17 * n)
    raw = np.empty(17 * n, np.uint8)

    def launch() -> None:
        kernel(gpu.queue, (-(-n // LOCAL) * LOCAL,), (LOCAL,), *field, int4(config.size),
               PLACE.pack(*config.origin, config.voxel_size), in_buf, np.int32(n), out_buf).wait()

    result = run_query(world, "points", data)
    encoded = msg.REQUEST_ENCODER.encode(msg.QueryResult(1, {k: msg.Array.of(a) for k, a in result.arrays.items()}))
    steps = {
        "checks (device_rows)": lambda: device_rows("points", data, config),
        "upload (a new buffer)": lambda: gpu.upload(inputs).release(),
        "kernel (launch + wait)": launch,
        "download (blocking)": lambda: cl.enqueue_copy(gpu.queue, raw, out_buf, is_blocking=True),
        "result -> msgspec bytes": lambda: msg.REQUEST_ENCODER.encode(
            msg.QueryResult(1, {k: msg.Array.of(a) for k, a in result.arrays.items()})),
        "msgspec bytes -> arrays": lambda: {k: a.numpy() for k, a in msg.decode_result(
            msg.msgspec.msgpack.decode(encoded), msg.QueryResult).arrays.items()},
    }
    for name, fn in steps.items():
        print(f"| {name} | {median_ms(fn, reps):.3f} |")
    in_buf.release()
    out_buf.release()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default=None, help="a device name fragment (default: the first usable)")
    ap.add_argument("--url", default=None, help="also time through this server")
    ap.add_argument("--reps", type=int, default=30)
    ap.add_argument("--breakdown", action="store_true", help="also time the steps of one points query")
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
            if args.breakdown:
                print(f"\n| {metric}: 100,000 points, step | ms (median) |\n| --- | --- |")
                breakdown(world, rows("points", rng, 0.5), args.reps)
                print("\n| metric | kind | rows | engine path ms (median) |\n| --- | --- | --- | --- |")
        finally:
            world.release()
    if args.url:
        import httpx

        from sdfserver import wire
        http = httpx.Client(base_url=args.url, timeout=60)
        print("\n| metric | kind | rows | HTTP round trip ms (median) | of which the client's encoding and decoding |"
              "\n| --- | --- | --- | --- | --- |")
        for metric in ("manhattan", "euclidean"):
            wid = http.post("/v1/worlds", json={"size": list(SIZE), "chunk_size": 32, "max_distance": 32,
                                                "metric": metric, "voxel_size": 0.5}).json()["id"]
            r = http.post(f"/v1/worlds/{wid}/edits", json={"edits": scene()})
            version = r.json()["version"]
            headers = {"content-type": wire.CONTENT_TYPE, "accept": wire.CONTENT_TYPE}
            for kind in COUNTS:
                sent = rows(kind, rng, 0.5)
                body = wire.encode({kind: sent})

                def ask() -> None:
                    answer = http.post(f"/v1/worlds/{wid}/query?min_version={version}", content=body, headers=headers)
                    assert answer.status_code == 200, answer.text
                ms = median_ms(ask, args.reps)
                answer = http.post(f"/v1/worlds/{wid}/query", content=body, headers=headers).content
                client_ms = median_ms(lambda: (wire.encode({kind: sent}),
                                               wire.decode_arrays(wire.decode(answer))), args.reps)
                print(f"| {metric} | {kind} | {COUNTS[kind]} | {ms:.3f} | {client_ms:.3f} |")
            http.delete(f"/v1/worlds/{wid}")


if __name__ == "__main__":
    main()
