"""Worlds up to 2048^3 voxels on one device: create, regenerate, brush, and check against scipy.

    PYTHONPATH=. python tools/large_worlds.py --sizes 1280,1536,2048 --out large_worlds.json

For each cubic size (chunk 32, cap 255, algorithm exact by default): create the world through
the library and time it; paint a seeded scene (a few hundred spheres and boxes over the whole
world, a few more in each checked window, boxes touching every corner, one erasing box); time
the full exact regeneration (``mark_all_dirty`` then ``recompute``, which finishes the queue);
time a radius-8 sphere brush at the centre followed by ``recompute`` (added and erased in turn);
then compare the field with scipy's ``distance_transform_cdt(metric="taxicab")`` on windows at
the 8 corners and the centre. A window's oracle reads the voxels of the window grown by cap + 1
(clipped to the world; outside the world is air): a voxel outside that box is at least cap + 2
from every voxel of the window, so the capped oracle is exact. Windows are checked in worker
processes while the device moves on to nothing else. One table at the end; everything in the
JSON file ``--out``. Each world is released before the next; a size that does not fit the
device is reported as refused.

Small sizes run anywhere, e.g. ``--sizes 64,128`` on PoCL.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import itertools
import json
import multiprocessing
import os
import statistics
import subprocess
import sys
import time
from datetime import datetime, timezone

import numpy as np
from scipy.ndimage import distance_transform_cdt

from sdfserver.edits import BoxEdit, SphereEdit
from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext
from sdfserver.world import World, WorldConfig

BATCH_OPS = 256


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def windows(n: int, side: int) -> dict[str, Box]:
    """The 8 corner windows and the centre one of a cubic world of side n."""
    side = min(side, n)
    out = {}
    for corner in range(8):
        lo = tuple(n - side if corner >> axis & 1 else 0 for axis in range(3))
        out["corner " + "".join("+" if corner >> axis & 1 else "-" for axis in range(3))] = \
            Box(lo, tuple(v + side for v in lo))
    c = n // 2 - side // 2
    out["centre"] = Box((c, c, c), (c + side, c + side, c + side))
    return out


def scene(n: int, shapes: int, checked: dict[str, Box], rng: np.random.Generator) -> list:
    """Spheres and boxes over the whole world, a few in and around each checked window, a box
    at every corner of the world, and one box that erases whatever it crosses."""
    def colour():
        return int(rng.integers(1, 256))

    def sphere(lo, hi, r_max):
        return SphereEdit(center=tuple(float(rng.uniform(a, b)) for a, b in zip(lo, hi)),
                          radius=float(rng.uniform(2, r_max)), colour=colour())

    def box(lo, hi, side_max):
        a = [int(rng.integers(l, max(l + 1, h))) for l, h in zip(lo, hi)]
        b = [min(n, v + int(rng.integers(1, side_max + 1))) for v in a]
        return BoxEdit(min=tuple(a), max=tuple(b), colour=colour())

    edits = []
    for _ in range(shapes):
        edits.append(sphere((0, 0, 0), (n, n, n), 24) if rng.random() < 0.5 else box((0, 0, 0), (n, n, n), 32))
    for w in checked.values():
        lo, hi = tuple(max(0, v - 16) for v in w.lo), tuple(min(n, v + 16) for v in w.hi)
        edits += [sphere(lo, hi, 10) for _ in range(2)] + [box(lo, hi, 12) for _ in range(2)]
    for corner in range(8):
        lo = tuple(n - 3 if corner >> axis & 1 else 0 for axis in range(3))
        edits.append(BoxEdit(min=lo, max=tuple(v + 3 for v in lo), colour=colour()))
    eraser = box((0, 0, 0), (n, n, n), max(8, n // 4))
    edits.append(BoxEdit(min=eraser.min, max=eraser.max, colour=0))
    return edits


def check_window(voxels: np.ndarray, field: np.ndarray, inner: tuple, cap: int) -> dict:
    """Compare one window's packed field with scipy's capped taxicab transform of the voxels
    around it (``inner``: the window's slices inside ``voxels``), as the project's tests do."""
    if voxels.any():
        expected = np.minimum(distance_transform_cdt(voxels == 0, metric="taxicab")[inner], cap)
    else:
        expected = np.full(field.shape, cap)
    distance_wrong = int(np.count_nonzero((field >> 8) != expected))
    colour_wrong = int(np.count_nonzero((field & 0xFF) != voxels[inner]))
    return {"equal": distance_wrong == 0 and colour_wrong == 0, "distance_mismatches": distance_wrong,
            "colour_mismatches": colour_wrong, "solid_voxels": int(np.count_nonzero(voxels[inner])),
            "max_distance": int((field >> 8).max())}


def timed_ms(fn, repeats: int) -> tuple[list[float], list[float]]:
    """Wall ms and device ms (summed kernel time) of ``fn`` (which returns a RecomputeResult)."""
    wall, device = [], []
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        wall.append((time.perf_counter() - start) * 1e3)
        device.append(result.device_ms)
    return wall, device


def run_size(gpu: GpuContext, n: int, args, pool: cf.Executor) -> dict:
    config = WorldConfig(size=(n, n, n), chunk_size=args.chunk, max_distance=args.cap, algorithm=args.algorithm)
    row = {"size": n, "voxels": n ** 3, "device_bytes": sum(World.buffer_bytes(config.validated()))}
    log(f"{n}^3: creating ({row['device_bytes'] / 2**20:.0f} MiB)")
    start = time.perf_counter()
    try:
        world = World(gpu, config)
    except DeviceMemoryExceeded as exc:
        row.update(refused=str(exc))
        log(f"{n}^3: refused: {exc}")
        return row
    try:
        row["create_s"] = time.perf_counter() - start
        checked = windows(n, args.window)
        rng = np.random.default_rng([args.seed, n])
        edits = scene(n, args.shapes, checked, rng)
        start = time.perf_counter()
        for first in range(0, len(edits), BATCH_OPS):
            world.apply_edits(edits[first:first + BATCH_OPS])
        world.recompute()  # builds the kernels the scene's regions need
        row.update(scene_ops=len(edits), scene_s=time.perf_counter() - start)
        log(f"{n}^3: created in {row['create_s']:.2f} s, scene painted and computed in {row['scene_s']:.2f} s")

        def regenerate():
            world.mark_all_dirty()
            return world.recompute()

        regenerate()  # the whole-world shape's passes, built once
        wall, device = timed_ms(regenerate, args.regen_repeats)
        row.update(full_regen_ms=wall, full_regen_device_ms=device,
                   full_regen_ms_median=statistics.median(wall),
                   full_regen_device_ms_median=statistics.median(device))
        log(f"{n}^3: full regeneration {row['full_regen_ms_median']:.1f} ms "
            f"(device {row['full_regen_device_ms_median']:.1f} ms)")

        centre = (n / 2, n / 2, n / 2)
        colours = itertools.cycle((0xE0, 0))  # painted, then erased

        def brush():
            world.apply_edits([SphereEdit(center=centre, radius=8.0, colour=next(colours))])
            return world.recompute()

        brush()  # the brush region's passes, built once
        wall, device = timed_ms(brush, args.brush_repeats)
        row.update(brush_ms=wall, brush_device_ms=device, brush_ms_median=statistics.median(wall),
                   brush_device_ms_median=statistics.median(device))
        log(f"{n}^3: radius-8 brush {row['brush_ms_median']:.2f} ms (device {row['brush_device_ms_median']:.2f} ms)")

        futures = {}
        for name, w in checked.items():
            grown = w.grow(args.cap + 1).intersect(world.world_box)
            inner = tuple(slice(a - g, b - g) for a, b, g in zip(w.lo[::-1], w.hi[::-1], grown.lo[::-1]))
            futures[name] = (w, pool.submit(check_window, world.read_voxels(grown), world.read_field(w),
                                            inner, args.cap))
        row["windows"] = [{"name": name, "lo": list(w.lo), "hi": list(w.hi), **future.result()}
                          for name, (w, future) in futures.items()]
        row["windows_equal"] = all(w["equal"] for w in row["windows"])
        log(f"{n}^3: windows equal to scipy: {row['windows_equal']}")
    finally:
        world.release()
    return row


def table(rows: list[dict]) -> str:
    lines = ["| size | voxels | device MiB | create s | full regen ms | brush ms | windows equal |",
             "| ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    for r in rows:
        if "refused" in r:
            lines.append(f"| {r['size']}^3 | {r['voxels']:,} | {r['device_bytes'] / 2**20:,.0f} | refused | | | |")
            continue
        lines.append(f"| {r['size']}^3 | {r['voxels']:,} | {r['device_bytes'] / 2**20:,.0f} | {r['create_s']:.2f} "
                     f"| {r['full_regen_ms_median']:.1f} | {r['brush_ms_median']:.2f} "
                     f"| {'yes' if r['windows_equal'] else 'NO'} |")
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", default="1280,1536,2048", help="cubic world sides, comma list")
    p.add_argument("--chunk", type=int, default=32)
    p.add_argument("--cap", type=int, default=255)
    p.add_argument("--algorithm", default="exact")
    p.add_argument("--window", type=int, default=64, help="side of each checked window, voxels")
    p.add_argument("--shapes", type=int, default=300, help="random spheres and boxes over the whole world")
    p.add_argument("--regen-repeats", type=int, default=3)
    p.add_argument("--brush-repeats", type=int, default=9)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default=None, help="as `sdfserver devices`: an index or a name substring")
    p.add_argument("--workers", type=int, default=min(9, os.cpu_count() or 1), help="processes checking windows")
    p.add_argument("--out", required=True, help="JSON file with every measurement")
    args = p.parse_args()

    gpu = GpuContext.create(args.device)
    log(f"device: {gpu.device_name}; budget {gpu.memory_budget_bytes / 2**20:,.0f} MiB, "
        f"largest buffer {gpu.max_allocation_bytes / 2**20:,.0f} MiB")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    report = {"device": gpu.device_name, "memory_budget_bytes": gpu.memory_budget_bytes,
              "max_allocation_bytes": gpu.max_allocation_bytes, "commit": commit or None,
              "date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "args": vars(args), "sizes": []}
    # Spawned, not forked: the workers only run scipy and must not inherit the device context.
    with cf.ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        for n in (int(s) for s in args.sizes.split(",")):
            report["sizes"].append(run_size(gpu, n, args, pool))
            with open(args.out, "w") as f:  # what has been measured survives a later failure
                json.dump(report, f, indent=1)
    print(table(report["sizes"]))
    ok = all(r.get("windows_equal", True) for r in report["sizes"])
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
