"""What one brush costs the engine thread on the host, beside its device time.

    python tools/launch_cost.py --device nvidia [--size 256] [--reps 500]

Applies random radius-5 sphere brushes to a world (cap 255) and recomputes after each, as the
server does for one client, and prints the medians of plan + apply (host), recompute wall time
and recompute device time; then the same for steps of 16 batches (as under many clients); then what one launch of the exact transform's first pass costs on
the host: the kernel call with its arguments, an enqueue with the arguments already set, and
the same on a queue without profiling.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pyopencl as cl

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sdfserver.algorithms.base import RegionJob  # noqa: E402
from sdfserver.algorithms.exact import Exact  # noqa: E402
from sdfserver.edits import parse_edits  # noqa: E402
from sdfserver.gpu import GpuContext  # noqa: E402
from sdfserver.world import World, WorldConfig  # noqa: E402


def per_call_us(gpu: GpuContext, fn, reps: int = 300) -> float:
    gpu.queue.finish()
    start = time.perf_counter()
    for _ in range(reps):
        fn()
    seconds = time.perf_counter() - start
    gpu.queue.finish()
    return seconds / reps * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default=None, help="as sdfserver serve --device")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--reps", type=int, default=500)
    args = ap.parse_args()
    gpu = GpuContext.create(args.device)
    n = args.size
    world = World(gpu, WorldConfig(size=(n, n, n), chunk_size=16, max_distance=255))
    rng = np.random.default_rng(1)

    def brush():
        return parse_edits([{"op": "sphere", "center": rng.integers(0, n, 3).tolist(), "radius": 5.0, "colour": 3}])

    for _ in range(50):  # builds and first-use costs out of the way
        world.apply_edits(brush())
        result = world.recompute()
    apply_us, wall_us, device_us = [], [], []
    for _ in range(args.reps):
        edits = brush()
        t0 = time.perf_counter()
        world.apply_plan(world.plan_edits(edits))
        t1 = time.perf_counter()
        result = world.recompute()
        apply_us.append((t1 - t0) * 1e6)
        wall_us.append((time.perf_counter() - t1) * 1e6)
        device_us.append(result.device_ms * 1e3)
    print(f"{gpu.device_name}, {n}^3, cap 255, radius-5 brushes, medians of {args.reps}:")
    print(f"  plan + apply (host)  {statistics.median(apply_us):7.1f} us")
    print(f"  recompute wall       {statistics.median(wall_us):7.1f} us")
    print(f"  recompute device     {statistics.median(device_us):7.1f} us")

    # A step under load applies many batches at once: their brushes go in one fill_brushes launch.
    step_apply_us, step_us = [], []
    for _ in range(args.reps):
        plans = [world.plan_edits(brush()) for _ in range(16)]
        t0 = time.perf_counter()
        world.apply_plans(plans)
        t1 = time.perf_counter()
        world.recompute()
        step_apply_us.append((t1 - t0) * 1e6)
        step_us.append((time.perf_counter() - t0) * 1e6)
    print(f"a step of 16 one-brush batches, medians of {args.reps}:")
    print(f"  apply (host)         {statistics.median(step_apply_us):7.1f} us")
    print(f"  apply + recompute    {statistics.median(step_us):7.1f} us")

    exact = Exact()
    job = RegionJob.seeded_region(world.buffers, result.regions[0], 255)
    shape = job.work_box.shape_xyz
    kernel, _, global_, local = exact.launch_shape(gpu, 0, shape[0], *shape, first=True)
    plain_queue = cl.CommandQueue(gpu.context)
    print("one launch of the x pass, host time:")
    print(f"  call with arguments          {per_call_us(gpu, lambda: exact.enqueue(gpu, job, kernel, global_, local)):7.1f} us")
    print(f"  enqueue, arguments set       {per_call_us(gpu, lambda: cl.enqueue_nd_range_kernel(gpu.queue, kernel, global_, local)):7.1f} us")
    print(f"  same, queue without profiling {per_call_us(gpu, lambda: cl.enqueue_nd_range_kernel(plain_queue, kernel, global_, local)):6.1f} us")
    plain_queue.finish()
    world.release()


if __name__ == "__main__":
    main()
