"""`sdfserver bench metrics`: what each metric and sign costs (issue 30, item 6).

For metric in (manhattan, euclidean) and signed in (false, true), on the same scene (`bench`'s
random spheres, seeded per size), chunk 32, cap 255:
  full      full regeneration per --sizes (median and min device ms over --reps after a warm-up,
            median wall ms); a size over the device's memory budget is skipped, saying so
  brush     a radius-8 sphere added, then erased, alternately, at random places and at the centre
            of the largest size: median device and wall ms of the incremental recompute
  queries   sdfserver.engine.query's run_query for points and spheres on the
            --query-size (or largest) world: wall ms, median over --reps
  accuracy  against scipy (distance_transform_cdt taxicab / distance_transform_edt, capped; signed:
            solids get minus the transform of the inverted mask padded with air) up to
            --accuracy-max-size, after the full regeneration and after the brushes: share of exact
            voxels and max abs error
  anchor    cupyx.scipy.ndimage.distance_transform_edt of the same voxels, when CuPy imports
            (cupy events, median after a warm-up), beside the Euclidean figure, and their ratio
A line on stderr per measurement; a Markdown table on stdout and in --out/metrics.md, every
figure in --out/metrics.json (rewritten after each measurement). Ctrl-C or SIGTERM keeps what
was measured (exit status 130). --quick is a CPU smoke run of seconds.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from sdfserver.bench.reference import scipy_distances
from sdfserver.bench.run import Results, progress, source_commit, stoppable
from sdfserver.bench.scene import populate
from sdfserver.bench.timing import cupy_event_ms, summarize
from sdfserver.edits import EditLimits, SphereEdit
from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.gpu import GpuContext
from sdfserver.world import World, WorldConfig

LIMITS = EditLimits(max_ops_per_batch=4096)
BRUSH_RADIUS_VOX = 8.0


def label(metric: str, signed: bool) -> str:
    return metric + (" signed" if signed else "")


def measure_full(world: World, args, row: dict, results: Results) -> float | None:
    world.mark_all_dirty()
    world.recompute()  # warm-up: builds the programs
    device, wall = [], []
    for _ in range(args.reps):
        world.mark_all_dirty()
        result = world.recompute()
        device.append(result.device_ms)
        wall.append(result.wall_ms)
    full = {**row, **summarize(device), "wall_median_ms": float(np.median(wall)), "device_bytes": world.device_bytes}
    results.add("full", full, f"{row['label']} {row['world_size']}^3: median {full['median_ms']:.4f} ms over {len(device)}")
    return full["median_ms"]


def measure_accuracy(world: World, args, row: dict, results: Results, after: str = "full") -> None:
    """``after``: what made the field, a full regeneration or the brushes' incremental recomputes."""
    progress(f"accuracy: {row['label']} {row['world_size']}^3 after {after}, against scipy")
    truth = scipy_distances(world.read_voxels(), row["metric"], row["signed"], args.max_distance)
    error = np.abs(world.read_distance().astype(np.float64) - truth)
    acc = {**row, "after": after, "exact_share": float((error == 0).mean()), "max_abs_error": float(error.max())}
    results.add("accuracy", acc, f"{row['label']} {row['world_size']}^3 after {after}: {100 * acc['exact_share']:.2f}% exact, "
                                 f"max error {acc['max_abs_error']:g}")


def measure_brush(world: World, args, row: dict, results: Results, rng: np.random.Generator) -> None:
    n = row["world_size"]
    margin = min(16.0, n / 4)
    for place in ("random", "centre"):
        device, wall = [], []
        for i in range(args.brushes):
            if i % 2 == 0:
                center = (n / 2,) * 3 if place == "centre" else tuple(float(v) for v in rng.uniform(margin, n - margin, 3))
            world.apply_edits([SphereEdit(center, BRUSH_RADIUS_VOX, int(rng.integers(1, 256)) if i % 2 == 0 else 0)])
            result = world.recompute()
            device.append(result.device_ms)
            wall.append(result.wall_ms)
        brush = {**row, "place": place, "radius": BRUSH_RADIUS_VOX, **summarize(device),
                 "wall_median_ms": float(np.median(wall))}
        results.add("brush", brush, f"{row['label']} {n}^3 {place}: median {brush['median_ms']:.4f} ms over {len(device)}")


def measure_queries(world: World, args, row: dict, results: Results, rng: np.random.Generator) -> None:
    """The engine thread's path of a points and a spheres query (engine/query.py run_query: checks,
    upload, one launch, download), wall ms; an HTTP request adds the transport
    (tools/query_timeline.py)."""
    from sdfserver.engine.query import run_query

    n = row["world_size"]
    points = rng.uniform(0, n, (args.points, 3)).astype(np.float32)
    spheres = np.column_stack([rng.uniform(0, n, (args.spheres, 3)),
                               rng.uniform(1, 16, args.spheres)]).astype(np.float32)
    for kind, rows in (("points", points), ("spheres", spheres)):
        run_query(world, kind, rows)  # warm-up: builds the program
        wall = []
        for _ in range(args.reps):
            start = time.perf_counter()
            run_query(world, kind, rows)
            wall.append((time.perf_counter() - start) * 1e3)
        q = {**row, "kind": kind, "count": len(rows), **summarize(wall)}
        results.add("queries", q, f"{row['label']} {n}^3 {len(rows)} {kind}: median {q['median_ms']:.3f} ms over {len(wall)}")


def cupy_edt():
    try:
        import cupy
        from cupyx.scipy.ndimage import distance_transform_edt

        cupy.cuda.runtime.getDeviceCount()
    except Exception:  # not installed, or no CUDA device: the anchor is left out
        return None
    return cupy, distance_transform_edt


def measure_anchor(voxels: np.ndarray, n: int, euclidean_ms: float | None, args, results: Results) -> None:
    cupy, edt = args.cupy
    progress(f"anchor: cupyx distance_transform_edt {n}^3")
    try:
        mask = cupy.asarray(voxels == 0)
        times = cupy_event_ms(lambda: edt(mask), args.reps)
    except cupy.cuda.memory.OutOfMemoryError as exc:
        results.add("anchor", {"world_size": n, "skipped": str(exc)}, f"cupyx edt {n}^3: skipped: {exc}")
        return
    finally:
        mask = None
        cupy.get_default_memory_pool().free_all_blocks()
    row = {"world_size": n, "anchor": "cupyx.scipy.ndimage.distance_transform_edt", **summarize(times),
           "euclidean_median_ms": euclidean_ms,
           "ratio": None if euclidean_ms is None else euclidean_ms / float(np.median(times))}
    results.add("anchor", row, f"cupyx edt {n}^3: median {row['median_ms']:.3f} ms over {len(times)}")


def run(gpu: GpuContext, args, results: Results) -> None:
    rng = np.random.default_rng(args.seed)
    brush_size = max(args.sizes)
    query_size = args.query_size if args.query_size in args.sizes else brush_size
    for n in args.sizes:
        voxels, euclidean_ms = None, None
        for metric, signed in args.combos:
            row = {"metric": metric, "signed": signed, "label": label(metric, signed), "world_size": n}
            progress(f"full: {row['label']} {n}^3, building")
            config = WorldConfig(size=(n, n, n), chunk_size=args.chunk_size, max_distance=args.max_distance,
                                 metric=metric, signed=signed)
            try:
                world = World(gpu, config, LIMITS)
            except DeviceMemoryExceeded as exc:
                results.add("full", {**row, "skipped": str(exc)}, f"{row['label']} {n}^3: skipped: {exc}")
                if n in (brush_size, query_size):
                    results.data["notes"].append(f"{row['label']} {n}^3 did not fit: no brush or queries for it")
                continue
            try:
                populate(world, np.random.default_rng(args.seed + n))  # one scene per size
                median_ms = measure_full(world, args, row, results)
                if n <= args.accuracy_max_size:
                    measure_accuracy(world, args, row, results)
                if n == query_size:
                    measure_queries(world, args, row, results, rng)
                if n == brush_size:
                    measure_brush(world, args, row, results, rng)
                    if n <= args.accuracy_max_size:
                        measure_accuracy(world, args, row, results, after="brushes")
                if args.cupy and metric == "euclidean" and not signed:
                    voxels, euclidean_ms = world.read_voxels(), median_ms
            finally:
                world.release()
        if args.cupy and voxels is not None:
            measure_anchor(voxels, n, euclidean_ms, args, results)


def format_markdown(data: dict) -> str:
    lines = [f"device: {data.get('device')}; commit {data.get('commit')}; {data.get('date')}",
             f"command: `{' '.join(data.get('argv', []))}`", ""]
    if data.get("interrupted"):
        lines.append("interrupted: the tables hold the measurements taken before the stop\n")

    def table(title: str, head: list[str], rows: list[list]) -> None:
        if rows:
            lines.extend([f"### {title}", "", "| " + " | ".join(head) + " |", "|" + " --- |" * len(head)])
            lines.extend("| " + " | ".join(str(v) for v in r) + " |" for r in rows)
            lines.append("")

    def ms(v) -> str:
        return "" if v is None else f"{v:.4f}"

    def done(r: dict, *cells) -> list:
        return [r.get("skipped", "skipped")] + [""] * (len(cells) - 1) if "skipped" in r else list(cells)

    table("Full regeneration (device ms; wall ms)", ["field", "world", "median", "min", "wall median", "MiB"],
          [[r["label"], f"{r['world_size']}³",
            *done(r, ms(r.get("median_ms")), ms(r.get("min_ms")), ms(r.get("wall_median_ms")),
                  f"{r.get('device_bytes', 0) / 2**20:.1f}")] for r in data.get("full", [])])
    table("Radius-8 brush, incremental recompute (device ms; wall ms)", ["field", "world", "place", "median", "wall median"],
          [[r["label"], f"{r['world_size']}³", r["place"], ms(r["median_ms"]), ms(r["wall_median_ms"])]
           for r in data.get("brush", [])])
    table("Queries (wall ms, median)", ["field", "world", "kind", "count", "median"],
          [[r["label"], f"{r['world_size']}³", r["kind"], *done(r, r.get("count"), ms(r.get("median_ms")))]
           for r in data.get("queries", [])])
    table("Accuracy against scipy", ["field", "world", "after", "exact %", "max abs error"],
          [[r["label"], f"{r['world_size']}³", r["after"], f"{100 * r['exact_share']:.2f}", f"{r['max_abs_error']:g}"]
           for r in data.get("accuracy", [])])
    table("Anchor: cupyx distance_transform_edt (cupy events) beside euclidean's full regeneration",
          ["world", "cupyx median ms", "euclidean median ms", "euclidean / cupyx"],
          [[f"{r['world_size']}³", *done(r, ms(r.get("median_ms")), ms(r.get("euclidean_median_ms")),
                                        "" if r.get("ratio") is None else f"{r['ratio']:.3f}")]
           for r in data.get("anchor", [])])
    if data.get("notes"):
        lines.extend(["Notes:", *[f"- {n}" for n in data["notes"]]])
    return "\n".join(lines)


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="sdfserver bench metrics", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="OpenCL device: index or name substring (default: prefer a GPU)")
    p.add_argument("--sizes", default="64,128,256,512,1024", help="world sides of the full regenerations")
    p.add_argument("--metrics", default="manhattan,euclidean")
    p.add_argument("--signed", default="false,true", help="comma list of false, true")
    p.add_argument("--chunk-size", type=int, default=32)
    p.add_argument("--max-distance", type=int, default=255)
    p.add_argument("--reps", type=int, default=5)
    p.add_argument("--brushes", type=int, default=20, help="brush edits per place (adding, erasing, ...)")
    p.add_argument("--query-size", type=int, default=512, help="queries on this world side (else the largest)")
    p.add_argument("--points", type=int, default=100_000)
    p.add_argument("--spheres", type=int, default=10_000)
    p.add_argument("--accuracy-max-size", type=int, default=256, help="scipy is slow beyond 256^3")
    p.add_argument("--seed", type=int, default=2025)
    p.add_argument("--memory-budget-mib", type=int, default=None,
                   help="device memory the worlds may use (default: the device's usual share)")
    p.add_argument("--no-cupy", action="store_true", help="leave out the cupyx anchor")
    p.add_argument("--quick", action="store_true", help="sizes 32,64, few reps: a smoke run for CPU devices")
    p.add_argument("--out", default="bench-metrics", help="directory for metrics.json and metrics.md")
    args = p.parse_args(argv)
    if args.quick:  # new defaults, parsed again so that options given explicitly still win
        p.set_defaults(sizes="32,64", reps=2, brushes=4, points=10_000, spheres=1_000)
        args = p.parse_args(argv)
    args.sizes = [int(v) for v in args.sizes.split(",") if v]
    metrics = [m for m in args.metrics.split(",") if m]
    signs = {"false": False, "true": True}
    if not args.sizes or set(metrics) - {"manhattan", "euclidean"} or not metrics:
        p.error("--sizes needs at least one size; --metrics is a comma list of manhattan, euclidean")
    if not set(args.signed.split(",")) <= set(signs):
        p.error("--signed is a comma list of false, true")
    args.combos = [(m, signs[s]) for m in metrics for s in args.signed.split(",")]
    return args


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = Results({"date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "commit": source_commit(),
                       "argv": ["sdfserver", "bench", "metrics", *argv], "seed": args.seed,
                       "chunk_size": args.chunk_size, "max_distance": args.max_distance, "reps": args.reps,
                       "notes": []},
                      str(out / "metrics.json"))
    args.cupy = None if args.no_cupy else cupy_edt()
    if args.cupy is None:
        results.data["notes"].append("no cupyx anchor: CuPy is not importable or sees no CUDA device"
                                     if not args.no_cupy else "no cupyx anchor: --no-cupy")
    with stoppable(results, "the tables and metrics.json hold what was measured") as outcome:
        progress("opening the OpenCL device")
        budget = None if args.memory_budget_mib is None else args.memory_budget_mib << 20
        gpu = GpuContext.create(args.device, budget)
        results.data["device"] = gpu.device_name
        progress(f"device: {gpu.device_name}")
        run(gpu, args, results)
        progress("done")
    results.data.setdefault("device", "(not opened)")
    report = format_markdown(results.data)
    print(report)
    (out / "metrics.md").write_text(report + "\n")
    results.save()
    return outcome.status
