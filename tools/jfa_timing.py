"""Jump flooding's full regeneration on ``sdfserver bench``'s world (the same seed and sizes, chunk
32, cap 255): device ms, the median of ``--reps`` after a warm-up, summed from OpenCL profiling
events as the bench sums them, and exactness against ``exact``'s field of the same world, for the
algorithm as the World runs it (``jfa``) and for other passes, in one process. The figure in
docs/benchmarks.md, against the kernel as it was before the weight-0 passes (its file copied into
kernels/, untracked):

    git show 316ff13:kernels/jfa.cl > kernels/jfa_before.cl
    python tools/jfa_timing.py --device nvidia --sizes 256,512 --reps 7 --before jfa_before.cl

Variants (``--variants``, comma-separated): ``jfa`` (World.recompute, as the bench times it);
``w0:XxYxZ`` or ``w1:XxYxZ`` (the weight-0 or the weighted passes in work-groups of that shape;
``:scalar`` for a voxel a work-item, ``:bXYZ`` for blocks of X groups of four along x, Y
and Z voxels along y and z, a stride apart, e.g. ``:b222``; ``:k=FILE`` for jfa.cl's kernels
built from another file in kernels/); ``before`` (``--before``'s kernels, with their arguments and
work-groups of 8x4x4, one launch each for its seed set-up and resolve); ``head`` (today's flood
with ``--head``'s kernel file in place of jfa.cl, e.g. ``git show HEAD:kernels/jfa.cl >
kernels/jfa_head.cl``, one voxel along y and z an item).
"""

from __future__ import annotations

import argparse
import json
import statistics
from typing import Callable

import numpy as np

from sdfserver.algorithms.base import AlgorithmRun, RegionJob, grid, init_work, int4, pack_region, run_whole
from sdfserver.algorithms.jfa import PassLayout, flood, step_sizes
from sdfserver.bench.scene import populate
from sdfserver.gpu import GpuContext
from sdfserver.gpu.profiling import event_ms
from sdfserver.world import World, WorldConfig

BENCH_SEED = 2025  # sdfserver bench's default --seed; its world of side n is drawn from seed + n


def flood_before(gpu: GpuContext, job: RegionJob, run: AlgorithmRun, filename: str, extra_passes: int = 0) -> None:
    """jfa.py's flood as it ran before the weight-0 path: ``filename``'s kernels, one launch a pass."""
    b, kernel = job.buffers, gpu.programs.kernel
    w_n, cap, chunk = int4(job.work_box.shape_xyz), np.int32(job.cap), np.int32(job.chunk)
    gsize, lsize = grid(job.work_box.shape_xyz)
    src, dst = b.seeds, b.seeds2
    run.events.append(kernel(filename, "jfa_seed_init")(gpu.queue, gsize, lsize, b.work, src, w_n, cap, chunk))
    for step in step_sizes(job, extra_passes):
        run.events.append(kernel(filename, "jfa_seed_pass")(gpu.queue, gsize, lsize, b.work, src, dst, w_n,
                                                            np.int32(step), cap, chunk))
        src, dst = dst, src
    run.events.append(kernel(filename, "jfa_resolve")(gpu.queue, gsize, lsize, b.work, src, b.work2, w_n, cap))


def with_kernel_file(gpu: GpuContext, filename: str, body: Callable[[], None]) -> None:
    """``body`` with jfa.cl's kernels built from ``filename`` (in kernels/) instead."""
    kernel = gpu.programs.kernel
    gpu.programs.kernel = lambda f, name, **defines: kernel(filename if f == "jfa.cl" else f, name, **defines)
    try:
        body()
    finally:
        gpu.programs.kernel = kernel


def variant(spec: str, before: str | None, head: str | None = None
            ) -> Callable[[GpuContext, RegionJob, AlgorithmRun], None] | None:
    """The flood ``spec`` names (None: ``jfa``, timed through the World)."""
    if spec == "jfa":
        return None
    if spec == "head":
        if head is None:
            raise SystemExit("variant 'head' needs --head FILE (a kernel file in kernels/)")
        return lambda gpu, job, run: with_kernel_file(gpu, head, lambda: run_whole(
            flood(gpu, job, run, job.buffers.work2, layout=PassLayout(block=(1, 1, 1)))))
    if spec == "before":
        if before is None:
            raise SystemExit("variant 'before' needs --before FILE (a kernel file in kernels/)")
        return lambda gpu, job, run: flood_before(gpu, job, run, before)
    weights, shape, *flags = spec.split(":")
    block = next((tuple(int(c) for c in f[1:]) for f in flags if f.startswith("b") and len(f) == 4), (1, 1, 1))
    layout = PassLayout(tuple(int(v) for v in shape.split("x")), "scalar" not in flags, block)
    filename = next((f[2:] for f in flags if f.startswith("k=")), "jfa.cl")
    return lambda gpu, job, run: with_kernel_file(gpu, filename, lambda: run_whole(
        flood(gpu, job, run, job.buffers.work2, weighted=weights == "w1", layout=layout)))


def time_variant(gpu: GpuContext, world: World, spec: str, before: str | None,
                 reps: int, head: str | None = None) -> tuple[list, list, np.ndarray]:
    """Device ms of each rep, the last rep's launches (ms), and the field's distances."""
    run_flood = variant(spec, before, head)
    times, launches = [], []
    for _ in range(reps + 1):
        if run_flood is None:
            world.mark_all_dirty()
            result = world.recompute()
            times.append(result.device_ms)
            launches = list(result.kernel_ms)
            continue
        job = RegionJob.seeded_region(world.buffers, world.world_box, world.config.max_distance)
        run = AlgorithmRun()
        run.events.append(init_work(gpu, job, job.buffers.work))
        run_flood(gpu, job, run)
        run.events.append(pack_region(gpu, job, job.buffers.work2))
        gpu.queue.finish()
        launches = [event_ms(e) for e in run.events]
        times.append(sum(t for t in launches if t is not None))
    return times[1:], launches, world.read_distance()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None)
    p.add_argument("--sizes", default="256,512")
    p.add_argument("--reps", type=int, default=7)
    p.add_argument("--before", default=None, help="a kernel file in kernels/ with the old jfa.cl")
    p.add_argument("--head", default=None, help="a kernel file in kernels/ with another jfa.cl (variant 'head')")
    p.add_argument("--variants", default=None,
                   help="default: before (with --before), jfa, w0:16x4x2:scalar, w1:16x4x2")
    p.add_argument("--json", default=None, help="write every figure here")
    args = p.parse_args()
    specs = (args.variants.split(",") if args.variants else
             (["before"] if args.before else []) + ["jfa", "w0:16x4x2:scalar", "w1:16x4x2"])
    gpu = GpuContext.create(args.device)
    print(f"device: {gpu.device_name}", flush=True)
    rows = []
    for n in [int(v) for v in args.sizes.split(",")]:
        world = World(gpu, WorldConfig((n, n, n), 32, 255, "jfa"))
        try:
            populate(world, np.random.default_rng(BENCH_SEED + n))
            reference = World(gpu, WorldConfig((n, n, n), 32, 255, "exact"))
            try:
                reference.load_voxels(world.read_voxels())
                reference.recompute()
                truth = reference.read_distance().astype(np.int32)
            finally:
                reference.release()
            for spec in specs:
                times, launches, field = time_variant(gpu, world, spec, args.before, args.reps, args.head)
                error = field.astype(np.int32) - truth
                row = {"size": n, "variant": spec, "median_ms": statistics.median(times), "min_ms": min(times),
                       "times_ms": times, "launches_ms": launches, "exact_share": float((error == 0).mean()),
                       "max_error": int(np.abs(error).max()), "underestimates": int((error < 0).sum())}
                rows.append(row)
                print(f"{n}^3 {spec:16s} median {row['median_ms']:8.3f} ms (min {row['min_ms']:8.3f}); "
                      f"{100 * row['exact_share']:.4f}% exact, max error {row['max_error']}; launches "
                      + " ".join(f"{t:.2f}" for t in launches if t is not None), flush=True)
        finally:
            world.release()
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"device": gpu.device_name, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
