"""Which request path to an engine running as a Ray actor is faster: a Ray actor method call, or
the engine's own sockets (what the API processes use)?

One EngineActor on a private local Ray cluster; requests that do no engine work, sequential
(each reply awaited before the next request) and pipelined (batches of --window in flight):

  ray: ray.get(actor.describe.remote())                       (the cluster process's call)
  zmq: EngineClient.call(msg.Status(...)) on its input/output  (the API processes' call; the name
       is from when the engine's sockets were ZeroMQ's, kept so that results compare)

The paths alternate within each round (and swap order every round) so that both see the same
machine state. Times are in microseconds; a pipelined call's time is its batch's time / window.

    python3 tools/ray_path_bench.py --calls 2000 --rounds 3 --out $OUT/ray-path.json
    python3 tools/ray_path_bench.py --device nvidia --engine-gpus 1 --out $OUT/ray-path.json
    python3 tools/ray_path_bench.py --calls 200 --warm-up 20 --rounds 1        # smoke
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import sys
import tempfile
import time

import numpy as np


def stats(per_call_ns: list[float], calls: int, elapsed_s: float) -> dict:
    us = np.asarray(per_call_ns) / 1e3
    return {"calls": calls, "p50_us": round(float(np.percentile(us, 50)), 1),
            "p90_us": round(float(np.percentile(us, 90)), 1), "p99_us": round(float(np.percentile(us, 99)), 1),
            "calls_per_s": round(calls / elapsed_s, 1)}


def ray_sequential(ray, actor, n: int) -> dict:
    times, started = [], time.perf_counter()
    for _ in range(n):
        t = time.perf_counter_ns()
        ray.get(actor.describe.remote())
        times.append(time.perf_counter_ns() - t)
    return stats(times, n, time.perf_counter() - started)


def ray_pipelined(ray, actor, n: int, window: int) -> dict:
    times, started = [], time.perf_counter()
    for _ in range(max(1, n // window)):
        t = time.perf_counter_ns()
        ray.get([actor.describe.remote() for _ in range(window)])
        times.append((time.perf_counter_ns() - t) / window)
    return stats(times, len(times) * window, time.perf_counter() - started)


async def zmq_sequential(client, msg, n: int) -> dict:
    times, started = [], time.perf_counter()
    for _ in range(n):
        t = time.perf_counter_ns()
        await client.call(msg.Status(client.next_id()))
        times.append(time.perf_counter_ns() - t)
    return stats(times, n, time.perf_counter() - started)


async def zmq_pipelined(client, msg, n: int, window: int) -> dict:
    times, started = [], time.perf_counter()
    for _ in range(max(1, n // window)):
        t = time.perf_counter_ns()
        await asyncio.gather(*(client.call(msg.Status(client.next_id())) for _ in range(window)))
        times.append((time.perf_counter_ns() - t) / window)
    return stats(times, len(times) * window, time.perf_counter() - started)


def measure(args, ray, actor, client, msg, loop) -> list[dict]:
    """Every round runs each (path, mode) once; the path that goes first alternates by round."""
    def one(path: str, mode: str, n: int) -> dict:
        if path == "ray":
            return ray_sequential(ray, actor, n) if mode == "seq" else ray_pipelined(ray, actor, n, args.window)
        coro = zmq_sequential(client, msg, n) if mode == "seq" else zmq_pipelined(client, msg, n, args.window)
        return loop.run_until_complete(coro)

    for path in ("ray", "zmq"):  # warm-up: connections, Ray's worker lease, caches; not reported
        for mode in ("seq", "pipe"):
            one(path, mode, args.warm_up)
    rows = []
    for r in range(args.rounds):
        order = ("ray", "zmq") if r % 2 == 0 else ("zmq", "ray")
        for mode in ("seq", "pipe"):
            for path in order:
                row = {"round": r + 1, "path": path, "mode": mode, **one(path, mode, args.calls)}
                rows.append(row)
                print(f"round {r + 1} {path:3} {mode:4} p50 {row['p50_us']:8.1f} us", file=sys.stderr)
    return rows


def table(rows: list[dict], window: int) -> str:
    lines = ["| round | path | mode | calls | p50 µs | p90 µs | p99 µs | calls/s |",
             "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        mode = "sequential" if row["mode"] == "seq" else f"{window} in flight"
        lines.append(f"| {row['round']} | {row['path']} | {mode} | {row['calls']} | {row['p50_us']:.1f} | "
                     f"{row['p90_us']:.1f} | {row['p99_us']:.1f} | {row['calls_per_s']:.0f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default=None, help="OpenCL device spec (default: the first that works)")
    parser.add_argument("--engine-gpus", type=float, default=0.0, help="GPUs the actor asks Ray for")
    parser.add_argument("--num-cpus", type=int, default=os.cpu_count(), help="CPUs of the local Ray cluster")
    parser.add_argument("--calls", type=int, default=2000, help="calls per path, mode and round")
    parser.add_argument("--warm-up", type=int, default=100, help="calls per path and mode before measuring")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--window", type=int, default=32, help="calls in flight when pipelined")
    parser.add_argument("--out", default=None, help="JSON file of every row")
    args = parser.parse_args()

    import ray

    from sdfserver.api.engine_client import EngineClient
    from sdfserver.cluster.engine_actor import EngineActor, free_ports
    from sdfserver.engine import messages as msg
    from sdfserver.engine.links import LinkLimits, new_credential
    from sdfserver.settings import Settings

    began, load_before = time.perf_counter(), os.getloadavg()  # other work on the machine skews both paths
    data_dir = tempfile.mkdtemp(prefix="sdf-ray-path-")
    # Ray's own temp directory, short (its sockets' paths are limited) and private: this cluster's
    # files and processes are told apart from any other Ray on the machine, which is left alone.
    ray_dir = tempfile.mkdtemp(prefix="rpb-")
    settings = Settings(device=args.device or "", warm_up=False, memory_budget_bytes=64 << 20, data_dir=data_dir,
                        sync=False, cluster="local", engines=1, engine_gpus=args.engine_gpus)
    # address="local": always a new cluster, never one found through RAY_ADDRESS or /tmp/ray
    ray.init(address="local", num_cpus=args.num_cpus, num_gpus=None, include_dashboard=False,
             _temp_dir=ray_dir, log_to_driver=True, configure_logging=False)
    loop = asyncio.new_event_loop()
    actor = client = None
    try:
        # as sdfserver/cluster/manager.py creates them, less the name and detachment (the actor
        # goes with this driver)
        credential = new_credential()
        actor = (ray.remote(EngineActor).options(num_gpus=args.engine_gpus, num_cpus=0)
                 .remote(settings.model_dump_json(), 0, 1, "127.0.0.1", tuple(free_ports(2)), credential))
        described = ray.get(actor.describe.remote(), timeout=600)
        print(f"engine: {described['device']} (pid {described['pid']}), {described['input']}", file=sys.stderr)
        client = EngineClient(described["input"], described["output"], credential, LinkLimits.of(settings))
        loop.run_until_complete(client.start())
        rows = measure(args, ray, actor, client, msg, loop)
    finally:
        if client is not None:
            loop.run_until_complete(client.stop())
        loop.close()
        if actor is not None:
            try:
                ray.get(actor.stop.remote(), timeout=60)  # the engine's thread ends, its data dir unlocked
            except Exception as exc:
                print(f"stopping the engine: {exc}", file=sys.stderr)
        ray.shutdown()
        shutil.rmtree(data_dir, ignore_errors=True)
        shutil.rmtree(ray_dir, ignore_errors=True)
    wall_s = round(time.perf_counter() - began, 1)

    def p50(path: str, mode: str) -> float:
        return float(np.median([r["p50_us"] for r in rows if r["path"] == path and r["mode"] == mode]))

    summary = {mode: {"ray_p50_us": p50("ray", mode), "zmq_p50_us": p50("zmq", mode),
                      "ray_over_zmq": round(p50("ray", mode) / p50("zmq", mode), 2)} for mode in ("seq", "pipe")}
    report = {"argv": sys.argv, "device": described["device"], "ray_version": ray.__version__,
              "calls": args.calls, "rounds": args.rounds, "window": args.window, "warm_up": args.warm_up,
              "engine_gpus": args.engine_gpus, "num_cpus": args.num_cpus, "cpus": os.cpu_count(),
              "loadavg_before": load_before, "loadavg_after": os.getloadavg(),
              "rows": rows, "summary": summary, "wall_s": wall_s}
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1)
    print(table(rows, args.window))
    for mode, s in summary.items():
        print(f"{mode}: median p50 ray {s['ray_p50_us']:.1f} us, zmq {s['zmq_p50_us']:.1f} us "
              f"(ray / zmq {s['ray_over_zmq']:.2f}); wall {wall_s} s", file=sys.stderr)


if __name__ == "__main__":
    main()
