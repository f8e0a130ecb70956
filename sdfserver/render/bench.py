"""The render benchmark: the dissertation's §3.5 scenario, Tables 4.1 and 4.3.

For each world size, algorithm and focus size: build the starting scene, then
for ``duration_s`` render frames as fast as possible (each read back to the
host, as a client would receive it) while a brush edit lands every
``edit_interval_ms`` — the seeded schedule of ``sdfserver.bench.schedule``,
the one the web demo's benchmark mode posts — and the field is recomputed
before the next frame. Frame time is the wall time from one frame to the next,
the recompute included when an edit landed (FPS = 1000 / dt_ms, equation
3.1); FPS is reported over all frames and over the frames in which a
recompute ran (§3.5.1). Chunks are 16^3 (§4.2.2) unless ``--chunk-size``
says otherwise ('whole': one chunk, the unchunked Table 4.1), never larger
than the world. Device times come from OpenCL profiling events. A line on
stderr as each run goes and ends; Ctrl-C or SIGTERM stops the benchmark with
the table (and the --json file, rewritten after each run) of the runs that
finished.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from typing import Any

import numpy as np

from sdfserver.algorithms import ALGORITHMS
from sdfserver.bench.run import Results, progress, stoppable
from sdfserver.bench.schedule import DEFAULT_SEED, EDIT_INTERVAL_MS, Schedule
from sdfserver.edits import parse_edits
from sdfserver.gpu import GpuContext
from sdfserver.render.camera import Camera
from sdfserver.render.renderer import Renderer
from sdfserver.render.scene import demo_scene
from sdfserver.world import World
from sdfserver.world_config import CHUNK_SIZES, Focus, WorldConfig

# §4.2.2: "the proceeding tests will use a chunk size of 16^3"
DEFAULT_CHUNK = 16


class NotAvailable(Exception):
    """A configuration this build cannot make (an algorithm or border mode not registered)."""


def _stats(samples: list[float]) -> dict[str, float]:
    a = np.asarray(samples, dtype=np.float64)
    if a.size == 0:
        return {"n": 0, "mean": math.nan, "std": math.nan, "ci95": math.nan, "p95": math.nan}
    std = float(a.std(ddof=1)) if a.size > 1 else 0.0
    return {"n": int(a.size), "mean": float(a.mean()), "std": std,
            "ci95": 1.96 * std / math.sqrt(a.size), "p95": float(np.percentile(a, 95))}


def chunk_for(size: int, chunk_size: int | None) -> int:
    """The chunk side for a cubic world: ``None`` is one chunk for the whole world (the
    dissertation's unchunked set-up, Table 4.1); a chunk never exceeds the world."""
    cs = size if chunk_size is None else min(chunk_size, size)
    if cs not in CHUNK_SIZES:
        raise NotAvailable(f"no chunk size fits a {size}^3 world as {chunk_size}; chunk sizes are {CHUNK_SIZES}")
    return cs


def world_config(size: int, algorithm: str, *, chunk_size: int | None = DEFAULT_CHUNK, borders: str | None = None,
                 focus: int | None = None, lod_algorithm: str | None = None,
                 max_distance: int = 255) -> WorldConfig:
    """A cubic world's config; ``focus`` is a centred cube of that many chunks a side (the
    dissertation's focus size, §4.6). Raises NotAvailable for what this build does not have."""
    cs = chunk_for(size, chunk_size)
    for name in (algorithm, lod_algorithm):
        if name is not None and name not in ALGORITHMS:
            raise NotAvailable(f"algorithm {name!r} is not registered here")
    extra: dict[str, Any] = {}
    if borders not in (None, "exact"):
        if "borders" not in {f.name for f in dataclasses.fields(WorldConfig)}:
            raise NotAvailable(f"borders={borders!r}: WorldConfig has no borders option in this build")
        extra["borders"] = borders
    if focus is not None:
        chunks = size // cs
        extra["focus"] = Focus((chunks // 2,) * 3, (min(focus, chunks),) * 3)
    if lod_algorithm is not None:
        extra["lod_algorithm"] = lod_algorithm
    return WorldConfig((size, size, size), cs, max_distance, algorithm, **extra)


def orbit(size: tuple[int, int, int], frame: int, width: int, height: int) -> Camera:
    sx, sy, sz = size
    angle = frame * 0.01
    r = 0.9 * max(sx, sz)
    position = (sx / 2 + r * math.sin(angle), sy * 0.7, sz / 2 + r * math.cos(angle))
    return Camera.look_at(position, (sx / 2, sy / 8, sz / 2), fov_y_deg=60.0,
                          width=width, height=height).validated()


def run_one(gpu: GpuContext, renderer: Renderer, size: int, algorithm: str, *, edit_interval_ms: float,
            duration_s: float, seed: int, width: int, height: int, progress=None,
            chunk_size: int | None = DEFAULT_CHUNK, borders: str | None = None, focus: int | None = None,
            lod_algorithm: str | None = None) -> dict[str, Any]:
    """One run of the §3.5 scenario. A frame "during recompute" is one in which an edit's
    recompute ran (§3.5.1 asks for FPS overall and during distance field computation)."""
    dims = (size, size, size)
    config = world_config(size, algorithm, chunk_size=chunk_size, borders=borders, focus=focus,
                          lod_algorithm=lod_algorithm)
    world = World(gpu, config)
    label = f"{algorithm} {size}^3 chunk {config.chunk_size}" + (f" focus {focus}" if focus else "")
    try:
        world.apply_edits(parse_edits(demo_scene(dims)))
        world.recompute()
        schedule = Schedule(dims, seed, edit_interval_ms)
        renderer.render(world, orbit(dims, 0, width, height))  # build and warm up
        frame_ms, recompute_frame_ms, render_device_ms, field_device_ms, field_wall_ms = [], [], [], [], []
        iterations = []
        start = last = next_edit = time.perf_counter()
        frames = 0
        shown = start
        while last - start < duration_s:
            now = time.perf_counter()
            edited = now >= next_edit
            if edited:
                world.apply_edits(parse_edits([schedule.next()]))
                result = world.recompute()
                field_device_ms.append(result.device_ms)
                field_wall_ms.append(result.wall_ms)
                iterations.append(result.iterations)
                next_edit = max(next_edit + edit_interval_ms / 1e3, now)
            frame = renderer.render(world, orbit(dims, frames, width, height))
            render_device_ms.append(frame.device_ms)
            now = time.perf_counter()
            frame_ms.append((now - last) * 1e3)
            if edited:
                recompute_frame_ms.append(frame_ms[-1])
            last = now
            frames += 1
            if progress is not None and now - shown >= 0.5:
                shown = now
                progress(f"{label}: {now - start:5.1f}/{duration_s:g} s, {frames} frames, "
                         f"{frames / (now - start):7.1f} FPS, {len(field_device_ms)} edits")
        return {
            "algorithm": algorithm, "world_size": size, "chunk_size": config.chunk_size,
            "borders": borders or "exact", "focus": focus, "lod_algorithm": lod_algorithm if focus else None,
            "frames": frames, "edits": len(field_device_ms),
            "duration_s": last - start, "fps": _stats([1e3 / dt for dt in frame_ms if dt > 0]),
            "fps_overall": frames / (last - start),
            "fps_recompute": _stats([1e3 / dt for dt in recompute_frame_ms if dt > 0]),
            "fps_recompute_overall": (len(recompute_frame_ms) / (sum(recompute_frame_ms) / 1e3)
                                      if recompute_frame_ms else math.nan),
            "frame_ms": _stats(frame_ms),
            "render_device_ms": _stats(render_device_ms),
            "field_device_ms": _stats(field_device_ms),
            "field_wall_ms": _stats(field_wall_ms),
            "iterations": _stats(iterations),
            "device_bytes": world.device_bytes,
        }
    finally:
        world.release()


def run_render_benchmark(gpu: GpuContext, *, world_sizes: list[int], algorithms: list[str],
                         edit_interval_ms: float = EDIT_INTERVAL_MS, duration_s: float = 10.0,
                         seed: int = DEFAULT_SEED, width: int = 1280, height: int = 720, progress=None,
                         results: Results | None = None, chunk_size: int | None = DEFAULT_CHUNK,
                         borders: str | None = None, focus_sizes: list[int | None] = (None,),
                         lod_algorithm: str | None = None) -> dict[str, Any]:
    """Every (algorithm, world size, focus size) run; results side by side. Each finished run is
    added to ``results`` (if given) as it ends, so a stop keeps the runs before it."""
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
                for focus in focus_sizes:
                    run = run_one(gpu, renderer, size, algorithm, edit_interval_ms=edit_interval_ms,
                                  duration_s=duration_s, seed=seed, width=width, height=height, progress=progress,
                                  chunk_size=chunk_size, borders=borders, focus=focus, lod_algorithm=lod_algorithm)
                    results.add("runs", run, f"{algorithm} {size}^3 chunk {run['chunk_size']}"
                                + (f" focus {focus}" if focus else "")
                                + f": {run['fps_overall']:.1f} FPS over {run['frames']} frames, "
                                f"{run['fps_recompute']['mean']:.1f} FPS while recomputing, {run['edits']} edits")
    finally:
        renderer.release()
    return results.data


def format_table(report: dict[str, Any]) -> str:
    """Tables 4.1 / 4.3 side by side: one row per algorithm (and focus), one column per world size."""
    sizes = sorted({r["world_size"] for r in report["runs"]})
    lines = [f"device: {report['device']}; {report['width']}x{report['height']}, an edit every "
             f"{report['edit_interval_ms']:g} ms, {report['duration_s']:g} s per run"
             + ("; interrupted, the runs that finished" if report.get("interrupted") else ""),
             "algorithm          metric                  " + "".join(f"{s:>18}^3" for s in sizes)]
    keys = dict.fromkeys((r["algorithm"], r.get("focus")) for r in report["runs"])
    for algorithm, focus in keys:
        by_size = {r["world_size"]: r for r in report["runs"] if (r["algorithm"], r.get("focus")) == (algorithm, focus)}
        name = algorithm + (f" focus {focus}" if focus else "")
        for label, key in (("FPS mean ± CI95", "fps"), ("FPS during recompute", "fps_recompute"),
                           ("field device ms", "field_device_ms"), ("render device ms", "render_device_ms")):
            cells = []
            for s in sizes:
                st = by_size[s][key] if s in by_size else None
                cells.append(f"{st['mean']:>11.2f} ± {st['ci95']:<6.2f}" if st and st["n"] else f"{'-':>20}")
            lines.append(f"{name:<18} {label:<23} " + "".join(cells))
    return "\n".join(lines)


def _chunk_arg(value: str) -> int | None:
    if value == "whole":
        return None
    if int(value) not in CHUNK_SIZES:
        raise argparse.ArgumentTypeError(f"chunk size must be 'whole' or one of {CHUNK_SIZES}")
    return int(value)


def _focus_arg(value: str) -> list[int | None]:
    return [None if v in ("none", "") else int(v) for v in value.split(",")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="sdfserver bench render", description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="32,64,128", help="world sides, comma-separated (voxels)")
    parser.add_argument("--algorithms", default="exact,jfa", help="comma-separated algorithm names")
    parser.add_argument("--chunk-size", type=_chunk_arg, default=DEFAULT_CHUNK,
                        help=f"chunk side, or 'whole' for one chunk per world (Table 4.1); default "
                             f"{DEFAULT_CHUNK} (§4.2.2), never more than the world")
    parser.add_argument("--borders", default=None, help="'padded': each chunk alone, outside counted solid (Table 4.3)")
    parser.add_argument("--focus", type=_focus_arg, default=[None],
                        help="focus sizes in chunks, comma-separated ('none' for no focus): a centred cube "
                             "where the algorithm runs, --lod-algorithm outside (§4.6)")
    parser.add_argument("--lod-algorithm", default="jfa", help="the algorithm outside the focus")
    parser.add_argument("--edit-interval-ms", type=float, default=EDIT_INTERVAL_MS)
    parser.add_argument("--duration", type=float, default=5.0, help="seconds per run")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--device", default=None, help="OpenCL device spec (index or name substring)")
    parser.add_argument("--json", default=None, help="write the JSON report here ('-': stdout)")
    args = parser.parse_args(argv)

    results = Results({"scenario": "render", "device": "(not opened)", "edit_interval_ms": args.edit_interval_ms,
                       "duration_s": args.duration, "width": args.width, "height": args.height, "runs": []},
                      None if args.json in (None, "-") else args.json)
    with stoppable(results, "the table and --json hold the runs that finished") as outcome:
        try:
            progress("opening the OpenCL device")
            gpu = GpuContext.create(args.device)
            run_render_benchmark(
                gpu, world_sizes=[int(s) for s in args.sizes.split(",")],
                algorithms=[a.strip() for a in args.algorithms.split(",")],
                edit_interval_ms=args.edit_interval_ms, duration_s=args.duration, seed=args.seed,
                width=args.width, height=args.height, progress=progress, results=results,
                chunk_size=args.chunk_size, borders=args.borders, focus_sizes=args.focus,
                lod_algorithm=args.lod_algorithm if any(args.focus) else None)
            progress("done")
        except NotAvailable as exc:
            parser.error(str(exc))
    if args.json == "-":
        print(json.dumps(results.data, indent=2))
    else:
        print(format_table(results.data))
        results.save()
    return outcome.status


if __name__ == "__main__":
    raise SystemExit(main())
