"""Sparse worlds on one device: terrain build, memory, brush and frame times (issue 20's targets).

    python tools/sparse_bench.py --out sparse_bench.json
    python tools/sparse_bench.py --sizes 512x128x512 --caps 15 --brushes 10 --frames 3 --out s.json  # CPU

For each cap (default 15 and 31) and each size in turn (default 8192x1024x8192, then 12288 and 16384
along x and z while they fit and time is left): create a sparse world (chunk 32), generate a terrain
(``sdfserver.sparse.terrain``) and time it (the queue finished); report stored bricks, bytes
per stored voxel (device bytes over stored voxels), the world's device bytes and the context's
allocated bytes. On the first size of each cap, also: ``--brushes`` radius-8 sphere brushes at
the terrain's surface (alternately adding and erasing), each timed from ``apply_edits`` to the
end of ``recompute`` (wall) with the recompute's kernel time (device, from profiling events);
``--frames`` 1280x720 frames over the terrain (plain, and with ambient occlusion and shadows),
the render kernel's device time, the frame's wall time and its pixels' SHA-256 (so that two
builds can be shown to draw the same image); and windows around the brushes
checked against scipy's taxicab transform (a window's oracle reads the window grown by the cap
plus one, so it is exact); with ``--places``, the brush at its worst place (``time_places``).
A dense 512^3 world (cap 31) takes the same brushes for comparison with dense worlds. A size that does not fit is reported as refused (507); sizes after it are
skipped, as are sizes once ``--budget-s`` has passed. The device is warmed up first as an engine
warms it up before serving (``--no-warm-up``: brushes compile the kernels they first need, and
``built_programs_at`` lists them). Everything goes to the JSON file
``--out``, a summary to stderr.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import sys
import time
from datetime import datetime, timezone

import numpy as np
from scipy.ndimage import distance_transform_cdt

from sdfserver.edits import SphereEdit
from sdfserver.engine.lifetime import warm_up
from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext
from sdfserver.render import Camera, RenderOptions, Renderer
from sdfserver.sparse.terrain import generate_terrain
from sdfserver.world_config import TerrainSpec
from sdfserver.sparse.world import SparseWorld
from sdfserver.world import World, WorldConfig

BRUSH_RADIUS = 8


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def summary(values: list[float]) -> dict:
    if not values:
        return {}
    ordered = sorted(values)
    return {"median": statistics.median(ordered), "p90": ordered[min(len(ordered) - 1, int(0.9 * len(ordered)))],
            "p99": ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))], "min": ordered[0],
            "max": ordered[-1], "n": len(ordered), "largest": ordered[-5:]}


def surface_at(world, x: int, z: int) -> tuple[int, int, int] | None:
    column = world.read_voxels(Box((x, 0, z), (x + 1, world.config.size[1], z + 1)))[0, :, 0]
    solid = np.flatnonzero(column)
    return (x, int(solid[-1]), z) if solid.size else None


def surface_points(world, rng: np.random.Generator, count: int) -> list[tuple[int, int, int]]:
    """Random columns' highest solid voxel (read through the world's own reads)."""
    sx, _, sz = world.config.size
    points = []
    while len(points) < count:
        point = surface_at(world, int(rng.integers(64, sx - 64)), int(rng.integers(64, sz - 64)))
        if point is not None:
            points.append(point)
    return points


def pool_shape(world) -> list[int]:
    """A sparse world's pool segment capacities (a dense world has none)."""
    return [seg.capacity for seg in world.pool.segments] if hasattr(world, "pool") else []


def time_brush(world, point: tuple[int, int, int], adding: bool) -> tuple[float, float]:
    """One radius-8 sphere brush at ``point``, adding or erasing: (wall ms from ``apply_edits`` to
    the end of ``recompute``, the recompute's kernel ms)."""
    edit = SphereEdit(tuple(float(v) for v in point), float(BRUSH_RADIUS), 0xE0 if adding else 0)
    start = time.perf_counter()
    world.apply_edits([edit])
    result = world.recompute()
    return (time.perf_counter() - start) * 1e3, result.device_ms


def time_brushes(world, points) -> dict:
    wall, device, grew, built = [], [], [], []
    for i, point in enumerate(points):
        segments, programs = pool_shape(world), len(world.gpu.programs)
        wall_ms, device_ms = time_brush(world, point, adding=i % 2 == 0)
        wall.append(wall_ms)
        device.append(device_ms)
        if pool_shape(world) != segments:
            grew.append(i)
        if len(world.gpu.programs) != programs:
            built.append(i)
    # the first may build kernels; a brush that grew the pool copied a segment's bricks, one that
    # built a program compiled it (a server builds them all at warm-up): each reported apart
    return {"wall_ms": summary(wall[1:]), "device_ms": summary(device[1:]),
            "pool_grew_at": grew, "built_programs_at": built,
            "wall_ms_without_growth": summary([w for i, w in enumerate(wall) if i and i not in grew])}


def time_places(world, rng: np.random.Generator, places: int, repeats: int) -> dict:
    """The brush at its worst place: ``repeats`` brushes (adding, then erasing, ...) at each of
    ``places`` surface places, half of them on a corner where four brick columns meet (the most
    bricks a radius-8 brush can touch); each place's median, and the worst of those medians. A
    place's median is its cost; a single slow brush anywhere is a host stall, not a place."""
    brick = world.config.chunk_size
    sx, _, sz = world.config.size
    found = []
    while len(found) < places:
        x, z = int(rng.integers(64, sx - 64)), int(rng.integers(64, sz - 64))
        if len(found) % 2:
            x, z = x // brick * brick, z // brick * brick
        point = surface_at(world, x, z)
        if point is not None:
            found.append(point)
    results = []
    for x, y, z in found:
        wall, device = zip(*(time_brush(world, (x, y, z), adding=k % 2 == 0) for k in range(repeats)))
        results.append({"place": [x, y, z], "on_corner": x % brick == 0 and z % brick == 0,
                        "wall_ms": summary(wall[1:]), "device_ms": summary(device[1:])})
    worst = max(results, key=lambda r: r["wall_ms"]["median"])
    medians = sorted(r["wall_ms"]["median"] for r in results)
    return {"repeats": repeats, "worst_place": worst["place"], "worst_median_ms": worst["wall_ms"]["median"],
            "worst_p90_ms": worst["wall_ms"]["p90"], "worst_device_median_ms": worst["device_ms"]["median"],
            "median_of_medians_ms": statistics.median(medians), "medians_ms": medians, "places": results}


def check_windows(world, points, cap: int) -> dict:
    checked, wrong = 0, 0
    for x, y, z in points:
        window = Box((x - 24, y - 24, z - 24), (x + 24, y + 24, z + 24)).intersect(world.world_box)
        grown = window.grow(cap + 1).intersect(world.world_box)
        voxels = world.read_voxels(grown)
        if voxels.any():  # scipy's transform of a box without solids is not the cap
            oracle = np.minimum(distance_transform_cdt(voxels == 0, metric="taxicab"), cap)
        else:
            oracle = np.full(voxels.shape, cap)
        expected = oracle[window.slices_zyx(grown.lo)]
        got = world.read_distance(window)
        checked += got.size
        wrong += int((got != expected).sum())
    return {"voxels_checked": checked, "voxels_wrong": wrong}


def time_frames(gpu, world, frames: int) -> dict:
    sx, sy, sz = world.config.size
    renderer = Renderer(gpu)
    camera = Camera.look_at((sx * 0.5, sy * 0.75, sz * 0.5 - 200.0), (sx * 0.5 + 600.0, sy * 0.3, sz * 0.5 + 900.0),
                            width=1280, height=720).validated()
    out = {}
    try:
        for name, options in (("plain", RenderOptions()),
                              ("ao_shadows", RenderOptions(ambient_occlusion=True, shadows=True))):
            renderer.render(world, camera, options)  # builds the kernel, uploads the brick table
            device, wall, ground = [], [], 0.0
            for _ in range(frames):
                frame = renderer.render(world, camera, options)
                device.append(frame.device_ms)
                wall.append(frame.wall_ms)
                ground = float((frame.pixels[..., :3] != [0x9C, 0xC8, 0xF0]).any(axis=-1).mean())
            out[name] = {"device_ms": summary(device), "wall_ms": summary(wall), "ground_fraction": ground,
                         "pixels_sha256": hashlib.sha256(frame.pixels.tobytes()).hexdigest()}
    finally:
        renderer.release()
    return out


def run_size(gpu, size, cap: int, args, rng, first: bool) -> dict:
    entry = {"size": list(size), "cap": cap, "chunk": 32}
    try:
        world = SparseWorld(gpu, WorldConfig(size, 32, cap, storage="sparse"))
    except DeviceMemoryExceeded as exc:
        return {**entry, "refused": str(exc)}
    try:
        start = time.perf_counter()
        try:
            generate_terrain(world, TerrainSpec(seed=args.seed))
        except DeviceMemoryExceeded as exc:
            return {**entry, "refused": str(exc)}
        entry["build_s"] = time.perf_counter() - start
        stored = world.stored_bricks
        entry.update(stored_bricks=stored, stored_voxels=stored * 32 ** 3,
                     bytes_per_stored_voxel=world.bytes_per_stored_voxel, device_bytes=world.device_bytes,
                     context_allocated_bytes=gpu.allocated_bytes,
                     logical_voxels=size[0] * size[1] * size[2])
        log(f"  {size} cap {cap}: built in {entry['build_s']:.1f} s, {stored} bricks, "
            f"{entry['bytes_per_stored_voxel']:.2f} B/stored voxel, {world.device_bytes / 2**30:.2f} GiB")
        if first:
            points = surface_points(world, rng, args.brushes)
            entry["brush"] = time_brushes(world, points)
            entry["brush"]["after_bytes_per_stored_voxel"] = world.bytes_per_stored_voxel
            log(f"    brush r{BRUSH_RADIUS}: wall {entry['brush']['wall_ms'].get('median', 0):.3f} ms, "
                f"device {entry['brush']['device_ms'].get('median', 0):.3f} ms (median)")
            if args.places:
                entry["places"] = time_places(world, rng, args.places, args.repeats)
                log(f"    worst of {args.places} places: median {entry['places']['worst_median_ms']:.3f} ms, "
                    f"p90 {entry['places']['worst_p90_ms']:.3f} ms at {entry['places']['worst_place']}")
            entry["frames"] = time_frames(gpu, world, args.frames)
            for name, f in entry["frames"].items():
                log(f"    frame {name}: device {f['device_ms']['median']:.3f} ms, wall {f['wall_ms']['median']:.3f} ms")
            worst = [tuple(entry["places"]["worst_place"])] if args.places else []
            entry["check"] = check_windows(world, points[: args.check_windows] + worst, cap)
            log(f"    scipy windows: {entry['check']}")
    finally:
        world.release()
    return entry


def dense_reference(gpu, args, rng) -> dict:
    side = args.dense_side
    world = World(gpu, WorldConfig((side, side, side), 32, 31))
    try:
        world.apply_edits([SphereEdit((side / 2, side / 4, side / 2), side / 4, 0x92)])
        world.recompute()
        points = [(int(rng.integers(16, side - 16)), side // 2, int(rng.integers(16, side - 16)))
                  for _ in range(args.brushes)]
        return {"size": [side] * 3, "cap": 31, "brush": time_brushes(world, points)}
    finally:
        world.release()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True)
    parser.add_argument("--sizes", default="8192x1024x8192,12288x1024x12288,16384x1024x16384")
    parser.add_argument("--caps", default="15,31")
    parser.add_argument("--brushes", type=int, default=50)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--check-windows", type=int, default=4)
    parser.add_argument("--places", type=int, default=0, help="places for the worst-place brush (0: none)")
    parser.add_argument("--repeats", type=int, default=21, help="brushes at each place")
    parser.add_argument("--dense-side", type=int, default=512)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--budget-s", type=float, default=420.0, help="start no new size after this")
    parser.add_argument("--device", default=None)
    parser.add_argument("--no-warm-up", dest="warm_up", action="store_false",
                        help="skip the engine's warm-up: brushes then compile kernels as they first need them")
    args = parser.parse_args()
    started = time.perf_counter()
    gpu = GpuContext.create(args.device)
    if args.warm_up:  # as an engine does before it serves: every exact variant a region can need
        warm_up(gpu)
    rng = np.random.default_rng(args.seed)
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    report = {"date": datetime.now(timezone.utc).isoformat(), "device": gpu.device_name,
              "memory_budget_bytes": gpu.memory_budget_bytes, "args": vars(args), "sparse": []}
    log(f"device: {gpu.device_name}")
    for cap in (int(c) for c in args.caps.split(",")):
        for i, size in enumerate(sizes):
            if i and time.perf_counter() - started > args.budget_s:
                report["sparse"].append({"size": list(size), "cap": cap, "skipped": "time budget"})
                continue
            entry = run_size(gpu, size, cap, args, rng, first=i == 0)
            report["sparse"].append(entry)
            if "refused" in entry:
                log(f"  {size} cap {cap}: refused ({entry['refused']})")
                break
            with open(args.out, "w") as f:  # what is done so far survives a stopped run
                json.dump(report, f, indent=1)
    if args.dense_side:
        report["dense"] = dense_reference(gpu, args, rng)
        log(f"dense {args.dense_side}^3 brush: wall {report['dense']['brush']['wall_ms']['median']:.3f} ms")
    report["elapsed_s"] = time.perf_counter() - started
    with open(args.out, "w") as f:
        json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
