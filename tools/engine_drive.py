"""How many edit batches one engine process takes, with no HTTP in the way.

Starts an engine process exactly as ``sdfserver serve`` does (``engine_main``, forked, its
flags parsed by the same settings), connects to it as an API process would (``EngineClient``:
typed requests over ZeroMQ), creates ``--worlds`` worlds (one by default; the clients spread
evenly over them) and keeps ``--clients`` requests in flight, each one edit batch of the load
test's random brushes, for ``--duration`` seconds. Prints batches/s,
the latency of a batch's request and answer, the engine process's CPU per batch (all its
threads, from /proc) and the engine's own counters (steps, batches a step, step phases).

    python tools/engine_drive.py --size 64 --clients 64 --duration 5 -- --device intel --no-persist

Everything after ``--`` is ``sdfserver serve`` flags. ``--json`` writes the figures; ``--trace FILE``
adds where each batch's time went inside the engine process (``tools/engine_trace.py``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import re
import shutil
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "clients"))

from loadtest.config import Brushes, LoadConfig  # noqa: E402
from service_overhead import cpu_seconds  # noqa: E402

from sdfserver.api.engine_client import EngineClient  # noqa: E402
from sdfserver.api.server import settings_from  # noqa: E402
from sdfserver.engine import messages as msg  # noqa: E402
from sdfserver.engine.proc import EngineAddress, engine_main  # noqa: E402
from sdfserver.engine.worlds import world_config_dict  # noqa: E402
from sdfserver.storage.codec import encode_batch  # noqa: E402
from sdfserver.world import WorldConfig  # noqa: E402

COUNTED = ("sdfserver_engine_steps_total", "sdfserver_edit_batches_total")


def threads_cpu_s(pid: int) -> dict[int, tuple[str, float]]:
    """Each thread of ``pid``: (its name as the kernel knows it, CPU seconds so far)."""
    out = {}
    for tid in map(int, os.listdir(f"/proc/{pid}/task")):
        try:
            out[tid] = (open(f"/proc/{pid}/task/{tid}/comm").read().strip(), cpu_seconds(pid, tid))
        except OSError:  # the thread ended
            continue
    return out


def counters(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for line in text.splitlines():
        match = re.match(r'(sdfserver_[a-z_]+)(\{phase="([a-z]+)"\})? ([0-9.e+-]+)$', line)
        if match and (match[1] in COUNTED or match[1] == "sdfserver_engine_phase_seconds_total"):
            out[match[3] or match[1]] = float(match[4])
    return out


async def drive(args: argparse.Namespace, address: EngineAddress, pid: int) -> dict:
    client = EngineClient(address.input, address.output)
    await client.start()
    config = WorldConfig(size=(args.size,) * 3, chunk_size=args.chunk_size, max_distance=args.max_distance)
    world_ids = [(await client.call(msg.CreateWorld(client.next_id(), world_config_dict(config))))["id"]
                 for _ in range(args.worlds)]
    load = LoadConfig(url="", world_size=(args.size,) * 3, ops_per_batch=args.ops_per_batch)
    latencies: list[float] = []
    stop_at = [0.0]

    async def one_client(seed: int) -> None:
        world_id = world_ids[seed % len(world_ids)]  # clients spread evenly over the worlds
        brushes = Brushes(seed, load)
        while time.perf_counter() < stop_at[0]:
            batch = encode_batch(brushes.batch()[0])
            started = time.perf_counter()
            await client.call(msg.ApplyEdits(client.next_id(), world_id, batch))
            latencies.append(time.perf_counter() - started)

    async def measured(seconds: float) -> tuple[int, float, float, float, dict, dict[str, float]]:
        latencies.clear()
        before = counters(await client.call(msg.MetricsText(client.next_id())))
        cpu, threads, started = cpu_seconds(pid), threads_cpu_s(pid), time.perf_counter()
        own_cpu = time.process_time()
        stop_at[0] = started + seconds
        await asyncio.gather(*(one_client(args.seed + i) for i in range(args.clients)))
        wall, cpu = time.perf_counter() - started, cpu_seconds(pid) - cpu
        own_cpu = time.process_time() - own_cpu
        threads = {tid: (name, cpu_s - threads[tid][1]) for tid, (name, cpu_s) in threads_cpu_s(pid).items()
                   if tid in threads}
        after = counters(await client.call(msg.MetricsText(client.next_id())))
        return len(latencies), wall, cpu, own_cpu, threads, {k: after[k] - before.get(k, 0.0) for k in after}

    await measured(args.warm_up)
    batches, wall, cpu, own_cpu, threads, engine = await measured(args.duration)
    await client.stop()
    steps = engine.get("sdfserver_engine_steps_total", 0.0)
    return {
        "clients": args.clients, "worlds": args.worlds, "size": args.size, "seconds": wall, "batches": batches,
        "batches_per_s": batches / wall, "p50_ms": float(np.percentile(latencies, 50)) * 1e3,
        "p99_ms": float(np.percentile(latencies, 99)) * 1e3, "engine_cpu_us_per_batch": cpu / batches * 1e6,
        "engine_cpu_share": cpu / wall, "driver_cpu_share": own_cpu / wall,
        "thread_cpu_us_per_batch": {f"{tid} {name}": round(cpu_s / batches * 1e6, 1)
                                    for tid, (name, cpu_s) in sorted(threads.items(), key=lambda t: -t[1][1])
                                    if cpu_s > 0}, "steps": steps, "batches_per_step": batches / steps if steps else None,
        "phases_s": {k: round(v, 3) for k, v in engine.items() if not k.startswith("sdfserver_")},
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--chunk-size", type=int, default=16)
    parser.add_argument("--max-distance", type=int, default=255, help="the worlds' cap")
    parser.add_argument("--clients", type=int, default=64)
    parser.add_argument("--worlds", type=int, default=1, help="spread the clients evenly over this many worlds")
    parser.add_argument("--ops-per-batch", type=int, default=1)
    parser.add_argument("--duration", type=float, default=5.0)
    parser.add_argument("--warm-up", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json")
    parser.add_argument("--trace", help="write where each batch's time went in the engine process here "
                                        "(tools/engine_trace.py) and add its summary to the figures")
    parser.add_argument("serve_flags", nargs="*", help="sdfserver serve flags (after --)")
    args = parser.parse_args()
    run_dir = tempfile.mkdtemp(prefix="sdfserver-drive-")
    flags = list(args.serve_flags)
    if "--data-dir" not in flags:
        flags += ["--data-dir", os.path.join(run_dir, "data")]
    settings = settings_from(flags)
    if args.trace:
        import engine_trace

        engine_trace.install(args.trace)
    address = EngineAddress(0, settings.device, f"ipc://{run_dir}/in", f"ipc://{run_dir}/out")
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)
    engine = context.Process(target=engine_main, args=(settings, address, 1, sender), name="sdfserver-engine-0")
    engine.start()
    try:
        if not receiver.poll(600):
            print("engine_drive: the engine did not start in 600 s", file=sys.stderr)
            return 1
        kind, said = receiver.recv()
        if kind != "ready":
            print(f"engine_drive: the engine cannot serve: {said}", file=sys.stderr)
            return 1
        print(f"engine_drive: engine process {engine.pid} on {said}", file=sys.stderr, flush=True)
        result = asyncio.run(drive(args, address, engine.pid))
        result["device"], result["flags"] = said, flags
    finally:
        engine.terminate()
        engine.join(10)
        shutil.rmtree(run_dir, ignore_errors=True)
    if args.trace:  # written by the engine process as it stopped
        import engine_trace

        result["in_engine"] = engine_trace.summarize(args.trace, since_s=args.warm_up)
    print(json.dumps(result, indent=1))
    if args.json:
        with open(args.json, "w") as out:
            json.dump(result, out, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
