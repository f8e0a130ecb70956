"""`sdfserver bench`: the dissertation's Tables 4.2, 4.4, 4.5 and 4.6, side by side, plus more.

Sections, each on any OpenCL device:
  chunks    one world of one chunk (8^3 .. 128^3) per algorithm: time of a full
            regeneration after random brush edits (mean, std, 95% CI) and FIM passes
  worlds    full-regeneration time per algorithm for worlds 64^3 .. 1024^3
  update    a radius-8 brush edit in the largest world: incremental device time per cap
  accuracy  each algorithm against scipy's oracle (`exact` above --scipy-max-world): share of exact voxels, max/mean error, underestimates;
            with --padded, those algorithms again with padded chunk borders (§4.2.1)
  anchors   scipy's distance_transform_cdt (CPU) and cupyx's distance_transform_edt (GPU), if installed
`sdfserver bench render ...` runs the rendering scenario instead (Tables 4.1 and 4.3; see --help there);
`sdfserver bench seed --out DIR` reproduces all of the dissertation's chapter 4 (see --help there);
`sdfserver bench metrics` compares the metrics and signs (see --help there).
Device times come from OpenCL profiling events (sum of kernel durations). A line
on stderr for each step and each measurement; the tables go to stdout, everything to
--json, which is rewritten after each measurement. Ctrl-C or SIGTERM stops the run and
prints the tables of what was measured (exit status 130). On a CPU device the full run
takes hours: --quick is the smoke run.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from datetime import datetime, timezone

import numpy as np

from sdfserver.algorithms import ALGORITHMS
from sdfserver.bench.reference import compare, scipy_distances
from sdfserver.bench.run import Results, progress, source_commit, stoppable
from sdfserver.bench.scene import populate
from sdfserver.bench.timing import cupy_event_ms, measure_chunk, summarize, time_full
from sdfserver.edits import EditLimits, SphereEdit
from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.gpu import GpuContext
from sdfserver.world import World, WorldConfig

ALL_ALGORITHMS = ["exact", "jfa", "jfa+1", "jfa+2", "jfa_fim", "fim", "brute"]
PADDED_ALGORITHMS = ["brute", "fim", "jfa", "jfa_fim"]  # also run with borders "padded" in the worlds section
SECTIONS = ["chunks", "worlds", "update", "anchors"]
# Brute force is O(n^6) on one chunk: beyond these sizes a single run takes minutes.
BRUTE_MAX_CHUNK = 64
BRUTE_MAX_WORLD = 64


def bench_chunks(gpu, args, rng, results: Results) -> None:
    for algorithm in args.algorithms:
        for cs in args.chunk_sizes:
            if algorithm == "brute" and cs > args.brute_max_chunk:
                continue
            progress(f"chunks: {algorithm} {cs}^3")
            row = measure_chunk(gpu, algorithm, cs, args.reps, rng, args.max_distance, args.limits)
            results.add("chunks", row, f"{algorithm} {cs}^3: mean {row['mean_ms']:.4f} ms over {row['n']}")


def bench_worlds(gpu, args, rng, results: Results) -> None:
    results.rows("accuracy")
    for n in args.world_sizes:
        reference = None
        runs = [(a, "exact") for a in args.algorithms] + [(a, "padded") for a in args.padded]
        for base, borders in runs:
            if base == "brute" and n > args.brute_max_world:
                continue
            algorithm = base if borders == "exact" else f"{base} padded"
            progress(f"worlds: {algorithm} {n}^3")
            try:
                world = World(gpu, WorldConfig((n, n, n), args.chunk_size, args.max_distance, base,
                                               borders=borders), args.limits)
            except DeviceMemoryExceeded as exc:
                results.add("worlds", {"algorithm": algorithm, "world_size": n, "skipped": str(exc)},
                            f"{algorithm} {n}^3: skipped: {exc}")
                continue
            try:
                populate(world, np.random.default_rng(args.seed + n))  # same scene for every algorithm
                times, iters, launches = time_full(world, args.reps)
                row = {"algorithm": algorithm, "world_size": n, **summarize(times),
                       "iterations_mean": float(np.mean(iters)),
                       "device_bytes": world.device_bytes,
                       "voxels_per_s": n ** 3 / (np.median(times) * 1e-3)}
                if len(launches) <= 8:
                    row["launches_ms"] = launches
                results.add("worlds", row, f"{algorithm} {n}^3: median {row['median_ms']:.4f} ms over {row['n']}")
                if n <= args.accuracy_max_world:
                    field = world.read_distance()
                    if reference is None:
                        reference = reference_field(world, n, args)
                    if reference is not None:
                        match = {**compare(algorithm, n, field, reference[0]), "reference": reference[1]}
                        results.add("accuracy", match, f"{algorithm} {n}^3: "
                                    f"{100 * match['exact_share']:.2f}% exact, max error {match['max_error']}")
            finally:
                world.release()


def reference_field(world: World, n: int, args) -> tuple[np.ndarray, str] | None:
    """What the algorithms are measured against: scipy's capped taxicab transform of the world's
    voxels up to --scipy-max-world, above it `exact`'s field (None until `exact` has run)."""
    if n <= args.scipy_max_world:
        return scipy_distances(world.read_voxels(), "manhattan", False, args.max_distance).astype(np.uint8), "scipy"
    if world.config.algorithm == "exact" and world.config.borders == "exact":
        return world.read_distance(), "exact"
    return None


def bench_update(gpu, args, rng, results: Results) -> None:
    n = args.update_world
    progress(f"update: building the {n}^3 world")
    try:
        world = World(gpu, WorldConfig((n, n, n), args.chunk_size, 255, "exact"), args.limits)
    except DeviceMemoryExceeded as exc:
        results.add("update", {"world_size": n, "skipped": str(exc)}, f"{n}^3 skipped: {exc}")
        return
    try:
        populate(world, np.random.default_rng(args.seed))
        for cap in args.update_caps:
            world.reconfigure(max_distance=cap)
            world.recompute()
            times, volumes = [], []
            progress(f"update: {n}^3 cap {cap}, {args.reps} edits")
            for i in range(args.reps):
                center = tuple(float(v) for v in rng.uniform(16, n - 16, 3))
                world.apply_edits([SphereEdit(center, 8.0, int(rng.integers(1, 256)) if i % 2 == 0 else 0)])
                result = world.recompute()
                times.append(result.device_ms)
                volumes.append(sum(r.volume for r in result.regions))
            row = {"world_size": n, "max_distance": cap, "radius": 8, **summarize(times),
                   "region_voxels_mean": float(np.mean(volumes))}
            results.add("update", row, f"{n}^3 cap {cap}: median {row['median_ms']:.4f} ms over {row['n']}")
    finally:
        world.release()


def bench_anchors(args, results: Results) -> None:
    from scipy.ndimage import distance_transform_cdt

    rng = np.random.default_rng(args.seed)
    for n in args.world_sizes:
        mask = rng.random((n, n, n)) > 0.001
        if n <= args.scipy_max_world:
            progress(f"anchors: scipy cdt {n}^3")
            t = time.perf_counter()
            distance_transform_cdt(mask, metric="taxicab")
            elapsed_ms = (time.perf_counter() - t) * 1e3
            results.add("anchors", {"anchor": "scipy.distance_transform_cdt (CPU, taxicab)", "world_size": n,
                                    "mean_ms": elapsed_ms, "n": 1}, f"scipy cdt {n}^3: {elapsed_ms:.3f} ms")
        try:
            import cupy
            from cupyx.scipy.ndimage import distance_transform_edt
        except ImportError:
            continue
        progress(f"anchors: cupyx edt {n}^3")
        gmask = cupy.asarray(mask)
        times = cupy_event_ms(lambda: distance_transform_edt(gmask), args.reps)
        row = {"anchor": "cupyx.distance_transform_edt (GPU, Euclidean)", "world_size": n, **summarize(times)}
        results.add("anchors", row, f"cupyx edt {n}^3: mean {row['mean_ms']:.3f} ms")
        gmask = None  # the next size's mask may need its memory


def format_tables(results: dict) -> str:
    lines = [f"device: {results['device']}", ""]
    if results.get("interrupted"):
        lines[1:1] = ["interrupted: the tables hold the measurements taken before the stop"]
    if results.get("chunks"):
        lines.append("Single chunk, full regeneration (Tables 4.2, 4.4, 4.5, 4.6)")
        lines.append(f"{'algorithm':<9} {'chunk':>6} {'mean ms':>10} {'std ms':>9} {'95% CI ms':>23} {'iters':>6}")
        for r in results["chunks"]:
            lo, hi = r["ci95_ms"]
            lines.append(f"{r['algorithm']:<9} {r['chunk_size']:>5}³ {r['mean_ms']:>10.4f} {r['std_ms']:>9.4f} "
                         f"({lo:>9.4f}, {hi:>9.4f}) {r['iterations_mean']:>6.2f}")
        lines.append("")
    if results.get("worlds"):
        lines.append("Whole world, full regeneration")
        lines.append(f"{'algorithm':<14} {'world':>6} {'median ms':>10} {'mean ms':>10} {'std ms':>9} {'Gvox/s':>8} {'iters':>6} {'MiB':>7}")
        for r in results["worlds"]:
            if "skipped" in r:
                lines.append(f"{r['algorithm']:<14} {r['world_size']:>5}³ skipped: {r['skipped']}")
                continue
            lines.append(f"{r['algorithm']:<14} {r['world_size']:>5}³ {r['median_ms']:>10.4f} {r['mean_ms']:>10.4f} "
                         f"{r['std_ms']:>9.4f} {r['voxels_per_s'] / 1e9:>8.2f} {r['iterations_mean']:>6.1f} "
                         f"{r['device_bytes'] / 2**20:>7.0f}")
        lines.append("")
    if results.get("update"):
        lines.append("Localized brush edit (radius 8), incremental update")
        for r in results["update"]:
            if "skipped" in r:
                lines.append(f"{r['world_size']}³ skipped: {r['skipped']}")
                continue
            lines.append(f"{r['world_size']}³ cap {r['max_distance']:>3}: median {r['median_ms']:.4f} ms, "
                         f"mean {r['mean_ms']:.4f} ± {r['std_ms']:.4f} ms, region {r['region_voxels_mean'] / 1e6:.1f} Mvox")
        lines.append("")
    if results.get("accuracy"):
        lines.append("Accuracy against scipy's capped taxicab transform (above --scipy-max-world: against exact)")
        lines.append(f"{'algorithm':<14} {'world':>6} {'exact %':>8} {'max err':>8} {'mean err':>9} {'under':>6}")
        for r in results["accuracy"]:
            lines.append(f"{r['algorithm']:<14} {r['world_size']:>5}³ {100 * r['exact_share']:>8.2f} "
                         f"{r['max_error']:>8} {r['mean_error']:>9.4f} {r['underestimates']:>6}")
        lines.append("")
    if results.get("anchors"):
        lines.append("Anchors")
        for r in results["anchors"]:
            lines.append(f"{r['anchor']:<46} {r['world_size']:>5}³ {r['mean_ms']:>10.3f} ms")
    return "\n".join(lines)


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="sdfserver bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="OpenCL device: index or name substring (default: prefer a GPU)")
    p.add_argument("--sections", default=",".join(SECTIONS),
                   help=f"comma list of: {', '.join(SECTIONS)} (accuracy comes with worlds)")
    p.add_argument("--algorithms", default=",".join(ALL_ALGORITHMS))
    p.add_argument("--padded", default=",".join(PADDED_ALGORITHMS),
                   help="of --algorithms, those the worlds section runs again with padded chunk borders "
                        "(each chunk alone, its outside solid; accuracy against exact)")
    p.add_argument("--chunk-sizes", default="8,16,32,64,128")
    p.add_argument("--world-sizes", default="64,128,256,512,1024")
    p.add_argument("--chunk-size", type=int, default=32, help="chunk size of the whole-world runs")
    p.add_argument("--max-distance", type=int, default=255)
    p.add_argument("--update-world", type=int, default=1024)
    p.add_argument("--update-caps", default="255,64,16")
    p.add_argument("--reps", type=int, default=20)
    p.add_argument("--seed", type=int, default=2025)
    p.add_argument("--brute-max-chunk", type=int, default=BRUTE_MAX_CHUNK)
    p.add_argument("--brute-max-world", type=int, default=BRUTE_MAX_WORLD)
    p.add_argument("--accuracy-max-world", type=int, default=512)
    p.add_argument("--scipy-max-world", type=int, default=256)
    p.add_argument("--quick", action="store_true", help="tiny sizes: a smoke run for CPU devices")
    p.add_argument("--json", default=None, help="write every result to this file")
    args = p.parse_args(argv)
    if args.quick:  # new defaults, parsed again so that options given explicitly still win
        p.set_defaults(chunk_sizes="8,16", world_sizes="32,64", update_world=64, update_caps="255,16",
                       reps=3, brute_max_world=32, brute_max_chunk=16)
        args = p.parse_args(argv)
    args.algorithms = [a for a in args.algorithms.split(",") if a]
    args.padded = [a for a in args.padded.split(",") if a in args.algorithms]
    unknown = set(args.algorithms) - set(ALGORITHMS)
    if unknown:
        p.error(f"unknown algorithms {sorted(unknown)}; choose from {sorted(ALGORITHMS)}")
    args.sections = {v for v in args.sections.split(",") if v}
    unknown = sorted(args.sections - set(SECTIONS))
    if unknown or not args.sections:
        p.error(f"unknown sections {unknown}; choose from {', '.join(SECTIONS)} (accuracy comes with worlds)")
    args.chunk_sizes = [int(v) for v in args.chunk_sizes.split(",")]
    args.world_sizes = [int(v) for v in args.world_sizes.split(",")]
    args.update_caps = [int(v) for v in args.update_caps.split(",")]
    args.limits = EditLimits(max_ops_per_batch=4096)
    return args


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    results = Results({"date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                       "host": platform.node(), "commit": source_commit(), "argv": sys.argv, "seed": args.seed},
                      args.json)
    with stoppable(results, "the tables and --json hold what was measured") as outcome:
        progress("opening the OpenCL device")
        gpu = GpuContext.create(args.device)
        results.data["device"] = gpu.device_name
        progress(f"device: {gpu.device_name}" + ("" if args.quick else "; --quick is the short run"))
        run_sections(gpu, args, results)
        progress("done")
    results.data.setdefault("device", "(not opened)")
    print(format_tables(results.data))
    results.save()
    return outcome.status


def run_sections(gpu: GpuContext, args: argparse.Namespace, results: Results) -> None:
    rng = np.random.default_rng(args.seed)
    if "chunks" in args.sections:
        bench_chunks(gpu, args, rng, results)
    if "worlds" in args.sections:
        bench_worlds(gpu, args, rng, results)
    if "update" in args.sections:
        bench_update(gpu, args, rng, results)
    if "anchors" in args.sections:
        bench_anchors(args, results)
