"""Full regeneration and the radius-8 brush, Manhattan against Euclidean (signed and not), in one
process on one device: the quick comparison behind the Euclidean kernel's tuning (the full
benchmark is ``sdfserver bench metrics``).

    python tools/edt_timing.py --sizes 256,512 --brush-size 1024 --reps 7
"""

from __future__ import annotations

import argparse
import statistics
import sys

import numpy as np

from sdfserver.edits import SphereEdit
from sdfserver.gpu import GpuContext
from sdfserver.world import World, WorldConfig


def fill(world: World, which: str) -> None:
    if which == "bench":
        from sdfserver.bench.scene import populate
        populate(world, np.random.default_rng(0))
        world.recompute()
    else:
        scene(world)


def scene(world: World, seed: int = 1) -> None:
    """Random spheres, about 2% of the world solid."""
    n = world.config.size[0]
    rng = np.random.default_rng(seed)
    count = max(4, int(0.02 * n ** 3 / (4 / 3 * np.pi * (n / 16) ** 3)))
    edits = [SphereEdit(center=tuple(float(v) for v in rng.uniform(0, n, 3)), radius=float(rng.uniform(n / 32, n / 12)),
                        colour=int(rng.integers(1, 256))) for _ in range(count)]
    for k in range(0, len(edits), 200):
        world.apply_edits(edits[k:k + 200])
    world.recompute()


def config(size, metric: str, signed: bool) -> WorldConfig:
    options = {} if (metric, signed) == ("manhattan", False) else {"metric": metric, "signed": signed}
    return WorldConfig(size=size, chunk_size=32, **options)


def median_ms(values: list[float]) -> str:
    return f"{statistics.median(values):8.3f} (min {min(values):7.3f})"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--sizes", default="256,512")
    p.add_argument("--brush-size", type=int, default=1024)
    p.add_argument("--reps", type=int, default=7)
    p.add_argument("--scene", choices=("spheres", "bench"), default="spheres",
                   help="spheres: a few large ones; bench: sdfserver bench's world (many small brushes)")
    p.add_argument("--kinds", default="manhattan,euclidean,manhattan-signed,euclidean-signed",
                   help="which fields; 'manhattan' alone runs on builds from before metrics existed")
    args = p.parse_args()
    gpu = GpuContext.create()
    print(f"device: {gpu.device.name}", flush=True)
    kinds = [(k.split("-")[0], k.endswith("-signed")) for k in args.kinds.split(",")]
    for n in [int(v) for v in args.sizes.split(",")]:
        for metric, signed in kinds:
            world = World(gpu, config((n, n, n), metric, signed))
            try:
                fill(world, args.scene)
                times = []
                for _ in range(args.reps + 1):
                    world.mark_all_dirty()
                    times.append(world.recompute().device_ms)
                last = world.last_recompute.kernel_ms
                print(f"full {n}^3 {metric:9s} signed={signed!s:5s}: {median_ms(times[1:])} ms "
                      f"(launches: {', '.join(f'{t:.3f}' for t in last[:8])})", flush=True)
            finally:
                world.release()
    n = args.brush_size
    for metric, signed in kinds:
        world = World(gpu, config((n, n, n), metric, signed))
        try:
            fill(world, args.scene)
            centre, times, walls = (n / 2, n / 2, n / 2), [], []
            for k in range(args.reps * 2 + 1):
                world.apply_edits([SphereEdit(center=centre, radius=8.0, colour=0xE0 if k % 2 == 0 else 0)])
                r = world.recompute()
                times.append(r.device_ms)
                walls.append(r.wall_ms)
            print(f"brush r8 centre {n}^3 {metric:9s} signed={signed!s:5s}: device {median_ms(times[1:])} ms, "
                  f"wall {median_ms(walls[1:])} ms", flush=True)
        finally:
            world.release()


if __name__ == "__main__":
    sys.exit(main())
