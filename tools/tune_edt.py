"""Tune the Euclidean transform's envelope stages (kernels/edt.cl edt_yz): each stage of a full
regeneration timed alone for several batch sizes and work-group widths, on the scene of
tools/edt_timing.py, after one full recompute has filled the stages' inputs.

    python tools/tune_edt.py --size 512 --batches 4,8,16 --groups 32,64,128,256 [--signed]
"""

from __future__ import annotations

import argparse
import statistics

import numpy as np

from sdfserver.algorithms.base import int4
from sdfserver.algorithms.euclidean import STAGE_AXES, _grid
from sdfserver.bench.scene import populate
from sdfserver.gpu import GpuContext
from sdfserver.world import World, WorldConfig
from edt_timing import scene


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--batches", default="4,8,16")
    p.add_argument("--groups", default="32,64,128,256")
    p.add_argument("--signed", action="store_true")
    p.add_argument("--reps", type=int, default=5)
    p.add_argument("--axes", default=",".join(map(str, STAGE_AXES)),
                   help="the second and the last stage's axes (1 = y, 2 = z): 2,1 or 1,2")
    p.add_argument("--scene", choices=("spheres", "bench"), default="spheres",
                   help="spheres: tools/edt_timing.py's few large ones; bench: sdfserver bench's world")
    args = p.parse_args()
    gpu = GpuContext.create()
    n = args.size
    world = World(gpu, WorldConfig(size=(n, n, n), chunk_size=32, metric="euclidean", signed=args.signed))
    if args.scene == "bench":
        populate(world, np.random.default_rng(0))
    else:
        scene(world)
    world.mark_all_dirty()
    world.recompute()
    b, cap = world.buffers, world.config.max_distance
    reference = world.read_field()
    print(f"device: {gpu.device.name}  {n}^3 signed={args.signed}")
    second, last = (int(v) for v in args.axes.split(","))
    for batch in [int(v) for v in args.batches.split(",")]:
        for width in [int(v) for v in args.groups.split(",")]:
            row = []
            for axis, source, target in ((second, b.work, b.edt_plane), (last, b.edt_plane, b.field)):
                kernel = gpu.programs.kernel("edt.cl", "edt_yz", SIGNED=int(args.signed), AXIS=axis,
                                             LAST=int(axis == last), BATCH=batch)
                group = (width, 1)
                grid = _grid((n, n), group)
                times = []
                for _ in range(args.reps + 1):
                    event = kernel(gpu.queue, grid, group, source, b.voxels, target, b.edt_stack, int4((n, n, n)),
                                   int4((0, 0, 0)), int4((n, n, n)), np.int32(cap))
                    event.wait()
                    times.append((event.profile.end - event.profile.start) * 1e-6)
                row.append(statistics.median(times[1:]))
            same = np.array_equal(world.read_field(), reference)
            print(f"batch {batch:3d} group {width:4d}: second {row[0]:.3f} ms  last {row[1]:.3f} ms  "
                  f"total {sum(row):.3f} ms  {'same field' if same else 'FIELD DIFFERS'}", flush=True)


if __name__ == "__main__":
    main()
