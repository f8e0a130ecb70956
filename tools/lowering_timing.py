"""A brush's recompute (radius 8 unless --radius) in a 1024^3 world (exact, cap 255; Manhattan and
Euclidean), lowered against the full transform of its cap-grown region (issue 33): device time
(OpenCL profiling events, summed over the recompute's launches) and wall time, median and max of
--reps, at the centre and at random places, for brushes that add solids (lowered:
algorithms/lower.py) and that erase a sphere placed there just before (raised: the transform of the
box where the field can rise; a Euclidean world takes its incremental transform), each beside the
same brush forced through the transform of its whole cap-grown region.

    source .whl/activate.sh; PYTHONPATH=$PWD python3 tools/lowering_timing.py --device nvidia [--size 1024] [--radius 64]
"""

from __future__ import annotations

import argparse
import json
import statistics

import numpy as np

from sdfserver.edits import SphereEdit
from sdfserver.gpu import GpuContext
from sdfserver.world import World, WorldConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default=None)
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--cap", type=int, default=255)
    parser.add_argument("--reps", type=int, default=50)
    parser.add_argument("--radius", type=float, default=8.0, help="the brush's radius, voxels")
    parser.add_argument("--metrics", default="manhattan,euclidean")
    parser.add_argument("--json", default="")
    args = parser.parse_args()
    gpu = GpuContext.create(args.device)
    n = args.size
    rows = {}
    for metric in args.metrics.split(","):
        world = World(gpu, WorldConfig(size=(n,) * 3, chunk_size=32, max_distance=args.cap, metric=metric))
        rng = np.random.default_rng(2025)
        world.apply_edits([SphereEdit(tuple(float(v) for v in rng.uniform(0, n, 3)), float(rng.uniform(4, 40)), 7)
                           for _ in range(64)])
        world.recompute()
        for place in ("centre", "random"):
            for kind in ("add, lowered", "add, full transform", "erase, raised", "erase, full transform"):
                device, wall = [], []
                for i in range(args.reps + 3):  # the first few build kernels and warm the caches
                    centre = (n / 2,) * 3 if place == "centre" else tuple(float(v) for v in rng.uniform(16, n - 16, 3))
                    if kind.startswith("erase"):  # a sphere there first, so that the erasing removes something
                        world.apply_edits([SphereEdit(centre, args.radius, 1 + i % 200)])
                        world.recompute()
                    world.apply_edits([SphereEdit(centre, args.radius, 0 if kind.startswith("erase") else 1 + i % 200)])
                    if kind.endswith("full transform"):  # the transform of the whole cap-grown region
                        world._lowering_boxes = lambda *_: None
                        world._rising_regions = lambda regions, runs: regions
                    result = world.recompute()
                    world.__dict__.pop("_lowering_boxes", None)
                    world.__dict__.pop("_rising_regions", None)
                    if i >= 3:
                        device.append(result.device_ms)
                        wall.append(result.wall_ms)
                rows[f"{metric}, {place}, {kind}"] = {
                    "device_ms_median": statistics.median(device), "device_ms_max": max(device),
                    "wall_ms_median": statistics.median(wall), "wall_ms_max": max(wall)}
        world.release()
    print(f"{gpu.device_name}; {n}^3, cap {args.cap}, a radius-{args.radius:g} sphere, {args.reps} each")
    print("| brush | device ms, median / max | wall ms, median / max |")
    print("| --- | --- | --- |")
    for name, r in rows.items():
        print(f"| {name} | {r['device_ms_median']:.3f} / {r['device_ms_max']:.3f} | "
              f"{r['wall_ms_median']:.3f} / {r['wall_ms_max']:.3f} |")
    if args.json:
        with open(args.json, "w") as out:
            json.dump(rows, out, indent=1)


if __name__ == "__main__":
    main()
