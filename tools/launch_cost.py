"""The host time one kernel launch costs the engine thread, with and without a profiling queue.

    python3 tools/launch_cost.py --device nvidia [--launches 20000] [--json FILE]

Enqueues a tiny kernel (one work-group writing one int) many times from this thread, as a
world's brush or transform launch is enqueued, and reports the host microseconds a launch:
on a queue made with ``PROFILING_ENABLE`` (the engine's queue: recompute device times come from
its events) and on a plain one; each with the arguments set again before every launch (a brush's
changing box) and with none set. The queue is finished every 256 launches, outside the timing,
so it never fills. Explains the per-world host cost of a step measured by
``tools/engine_cpu_bench.py --worlds N`` (docs/benchmarks.md, "Many worlds on one engine").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sdfserver.gpu.device import choose_device  # noqa: E402

SOURCE = """
__kernel void touch(__global int *out, int4 lo, int4 shape, float r2, uint colour)
{
    if (get_global_id(0) == 0)
        out[0] = lo.x + shape.y + (int)r2 + (int)colour;
}
"""
BATCH = 256


def launch_us(queue: cl.CommandQueue, kernel: cl.Kernel, out: cl.Buffer, launches: int, set_args: bool) -> float:
    rng = np.random.default_rng(1)
    args = [(rng.integers(0, 100, 4).astype(np.int32).tobytes(), np.int32(7).tobytes())
            for _ in range(BATCH)]
    kernel.set_arg(0, out)
    kernel._set_arg_buf(1, args[0][0])
    kernel._set_arg_buf(2, args[0][0])
    kernel._set_arg_buf(3, np.float32(4.0).tobytes())
    kernel._set_arg_buf(4, np.uint32(3).tobytes())
    spent = 0.0
    done = 0
    while done < launches:
        started = time.perf_counter()
        for lo, colour in args:
            if set_args:
                kernel._set_arg_buf(1, lo)
                kernel._set_arg_buf(2, lo)
                kernel._set_arg_buf(4, colour)
            cl.enqueue_nd_range_kernel(queue, kernel, (64,), (64,))
        spent += time.perf_counter() - started
        done += BATCH
        queue.finish()
    return spent / done * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None)
    ap.add_argument("--launches", type=int, default=20000)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    device = choose_device(args.device)
    context = cl.Context([device])
    kernel = cl.Program(context, SOURCE).build().touch
    out = cl.Buffer(context, cl.mem_flags.READ_WRITE, 4)
    queues = {"profiling": cl.CommandQueue(context, properties=cl.command_queue_properties.PROFILING_ENABLE),
              "plain": cl.CommandQueue(context)}
    results = {}
    for name, queue in queues.items():
        launch_us(queue, kernel, out, 2048, True)  # warm-up
        for set_args in (False, True):
            key = f"{name}, {'args set' if set_args else 'no args set'}"
            results[key] = min(launch_us(queue, kernel, out, args.launches, set_args) for _ in range(3))
    print(f"{device.name.strip()}: host us a launch (best of 3 runs of {args.launches})")
    for key, value in results.items():
        print(f"  {key:28s} {value:6.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"device": device.name.strip(), "us_per_launch": results}, indent=1))


if __name__ == "__main__":
    main()
