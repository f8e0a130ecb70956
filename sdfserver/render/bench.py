"""The render benchmark: the dissertation's §3.5 scenario, Tables 4.1 and 4.3.

For each world size and algorithm: build the starting scene, then for
``duration_s`` render frames as fast as possible (each read back to the host,
as a client would receive it) while a brush edit lands every
``edit_interval_ms`` — a sphere placed or erased at a random position with a
random radius, all from ``seed`` — and the field is recomputed before the
next frame. Frame time is the wall time from one frame to the next, the
recompute included when an edit landed (FPS = 1000 / dt_ms, equation 3.1);
device times come from OpenCL profiling events. A line on stderr as each run
goes and ends; Ctrl-C or SIGTERM stops the benchmark with the table (and the
--json file, rewritten after each run) of the runs that finished.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from typing import Any

import numpy as np

from sdfserver.benchrun import INTERRUPTED_EXIT, Results, progress, sigterm_interrupts
from sdfserver.edits import parse_edits
from sdfserver.gpu import GpuContext
from sdfserver.render.camera import Camera
from sdfserver.render.renderer import Renderer
from sdfserver.render.scene import demo_scene
from sdfserver.world import World, WorldConfig


def _stats(samples: list[float]) -> dict[str, float]:
    a = np.asarray(samples, dtype=np.float64)
    if a.size == 0:
        return {"n": 0, "mean": math.nan, "std": math.nan, "ci95": math.nan, "p95": math.nan}
    std = float(a.std(ddof=1)) if a.size > 1 else 0.0
    return {"n": int(a.size), "mean": float(a.mean()), "std": std,
            "ci95": 1.96 * std / math.sqrt(a.size), "p95": float(np.percentile(a, 95))}


def _random_brush(rng: np.random.Generator, size: tuple[int, int, int]) -> dict[str, Any]:
    centre = [float(rng.uniform(0, s)) for s in size]
    radius = float(rng.uniform(1, max(2.0, min(size) / 16)))
    colour = 0 if rng.random() < 0.5 else int(rng.integers(1, 256))
    return {"op": "sphere", "center": centre, "radius": radius, "colour": colour}


def _orbit(size: tuple[int, int, int], frame: int, width: int, height: int) -> Camera:
    sx, sy, sz = size
    angle = frame * 0.01
    r = 0.9 * max(sx, sz)
    position = (sx / 2 + r * math.sin(angle), sy * 0.7, sz / 2 + r * math.cos(angle))
    return Camera.look_at(position, (sx / 2, sy / 8, sz / 2), fov_y_deg=60.0,
                          width=width, height=height).validated()


def run_one(gpu: GpuContext, renderer: Renderer, size: int, algorithm: str, *, edit_interval_ms: float,
            duration_s: float, seed: int, width: int, height: int,
            progress=None) -> dict[str, Any]:
    dims = (size, size, size)
    world = World(gpu, WorldConfig(size=dims, algorithm=algorithm))
    try:
        world.apply_edits(parse_edits(demo_scene(dims)))
        world.recompute()
        rng = np.random.default_rng(seed)
        renderer.render(world, _orbit(dims, 0, width, height))  # build and warm up
        frame_ms, render_device_ms, field_device_ms, field_wall_ms = [], [], [], []
        start = last = next_edit = time.perf_counter()
        frames = 0
        shown = start
        while last - start < duration_s:
            now = time.perf_counter()
            if now >= next_edit:
                world.apply_edits(parse_edits([_random_brush(rng, dims)]))
                result = world.recompute()
                field_device_ms.append(result.device_ms)
                field_wall_ms.append(result.wall_ms)
                next_edit = max(next_edit + edit_interval_ms / 1e3, now)
            frame = renderer.render(world, _orbit(dims, frames, width, height))
            render_device_ms.append(frame.device_ms)
            now = time.perf_counter()
            frame_ms.append((now - last) * 1e3)
            last = now
            frames += 1
            if progress is not None and now - shown >= 0.5:
                shown = now
                progress(f"{algorithm} {size}^3: {now - start:5.1f}/{duration_s:g} s, {frames} frames, "
                         f"{frames / (now - start):7.1f} FPS, {len(field_device_ms)} edits")
        fps = [1e3 / dt for dt in frame_ms if dt > 0]
        return {
            "algorithm": algorithm, "world_size": size, "frames": frames, "edits": len(field_device_ms),
            "duration_s": last - start, "fps": _stats(fps),
            "fps_overall": frames / (last - start),
            "frame_ms": _stats(frame_ms),
            "render_device_ms": _stats(render_device_ms),
            "field_device_ms": _stats(field_device_ms),
            "field_wall_ms": _stats(field_wall_ms),
        }
    finally:
        world.release()


def run_render_benchmark(gpu: GpuContext, *, world_sizes: list[int], algorithms: list[str],
                         edit_interval_ms: float = 200.0, duration_s: float = 10.0, seed: int = 0,
                         width: int = 1280, height: int = 720, progress=None,
                         results: Results | None = None) -> dict[str, Any]:
    """Every (algorithm, world size) pair; results side by side. Each finished run is added to
    ``results`` (if given) as it ends, so a stop keeps the runs before it."""
    results = results or Results({}, None)
    results.data.update({
        "scenario": "render",
        "device": gpu.device_name,
        "edit_interval_ms": edit_interval_ms, "duration_s": duration_s, "seed": seed,
        "width": width, "height": height,
    })
    results.rows("runs")
    renderer = Renderer(gpu)
    try:
        for algorithm in algorithms:
            for size in world_sizes:
                run = run_one(gpu, renderer, size, algorithm, edit_interval_ms=edit_interval_ms,
                              duration_s=duration_s, seed=seed, width=width, height=height, progress=progress)
                results.add("runs", run, f"{algorithm} {size}^3: {run['fps_overall']:.1f} FPS over "
                            f"{run['frames']} frames, {run['edits']} edits")
    finally:
        renderer.release()
    return results.data


def format_table(report: dict[str, Any]) -> str:
    """Tables 4.1 / 4.3 side by side: one row per algorithm, one column per world size."""
    sizes = sorted({r["world_size"] for r in report["runs"]})
    lines = [f"device: {report['device']}; {report['width']}x{report['height']}, an edit every "
             f"{report['edit_interval_ms']:g} ms, {report['duration_s']:g} s per run"
             + ("; interrupted, the runs that finished" if report.get("interrupted") else ""),
             "algorithm  metric                  " + "".join(f"{s:>18}^3" for s in sizes)]
    for algorithm in dict.fromkeys(r["algorithm"] for r in report["runs"]):
        by_size = {r["world_size"]: r for r in report["runs"] if r["algorithm"] == algorithm}
        for label, key in (("FPS mean ± CI95", "fps"), ("field device ms", "field_device_ms"),
                           ("render device ms", "render_device_ms")):
            cells = []
            for s in sizes:
                st = by_size[s][key] if s in by_size else None
                cells.append(f"{st['mean']:>11.2f} ± {st['ci95']:<6.2f}" if st and st["n"] else f"{'-':>20}")
            lines.append(f"{algorithm:<10} {label:<23} " + "".join(cells))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sdfserver bench render", description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="32,64,128", help="world sides, comma-separated (voxels)")
    parser.add_argument("--algorithms", default="exact,jfa", help="comma-separated algorithm names")
    parser.add_argument("--edit-interval-ms", type=float, default=200.0)
    parser.add_argument("--duration", type=float, default=5.0, help="seconds per run")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--device", default=None, help="OpenCL device spec (index or name substring)")
    parser.add_argument("--json", default=None, help="write the JSON report here ('-': stdout)")
    args = parser.parse_args(argv)

    results = Results({"scenario": "render", "device": "(not opened)", "edit_interval_ms": args.edit_interval_ms,
                       "duration_s": args.duration, "width": args.width, "height": args.height, "runs": []},
                      None if args.json in (None, "-") else args.json)
    status = 0
    with sigterm_interrupts():
        try:
            progress("opening the OpenCL device")
            gpu = GpuContext.create(args.device)
            run_render_benchmark(
                gpu, world_sizes=[int(s) for s in args.sizes.split(",")],
                algorithms=[a.strip() for a in args.algorithms.split(",")],
                edit_interval_ms=args.edit_interval_ms, duration_s=args.duration, seed=args.seed,
                width=args.width, height=args.height, progress=progress, results=results)
            progress("done")
        except KeyboardInterrupt:
            results.data["interrupted"] = True
            progress("interrupted: the table and --json hold the runs that finished")
            status = INTERRUPTED_EXIT
    if args.json == "-":
        print(json.dumps(results.data, indent=2))
    else:
        print(format_table(results.data))
        results.save()
    return status


if __name__ == "__main__":
    raise SystemExit(main())
