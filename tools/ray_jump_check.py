"""Two builds of the ray marcher, one frame: which pixels differ, and which build is right there.

Builds the terrain of tools/sparse_bench.py (8192 x 1024 x 8192, cap 31, chunk 32, seed 1; no
brushes) and renders sparse_bench's 1280x720 frame. Run ``render`` and ``pick`` in each build's
tree; ``diff`` and ``judge`` in either:

    python3 tools/ray_jump_check.py render --out new.npz          # in each tree
    python3 tools/ray_jump_check.py diff new.npz old.npz --out pixels.npy
    python3 tools/ray_jump_check.py pick --pixels pixels.npy --out hits-new.npy   # in each tree
    python3 tools/ray_jump_check.py judge --pixels pixels.npy hits-new.npy hits-old.npy

``judge`` takes each differing pixel's ray in float64 and each build's hit voxel (a solid voxel):
a hit voxel the ray does not pass through is wrong; of two hits on the ray, the one entered later
passed the other, a solid, so it is wrong (a grazed voxel, entered and left at the same t, is
counted apart).
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

SIZE = tuple(int(v) for v in os.environ.get("JUMP_CHECK_SIZE", "8192,1024,8192").split(","))
CAP = 31


def world_and_camera(device: str | None):
    from sdfserver.gpu import GpuContext
    from sdfserver.sparse.world import SparseWorld
    from sdfserver.sparse.terrain import generate_terrain
    from sdfserver.world import WorldConfig
    from sdfserver.world_config import TerrainSpec

    gpu = GpuContext.create(device)
    world = SparseWorld(gpu, WorldConfig(SIZE, 32, CAP, storage="sparse"))
    generate_terrain(world, TerrainSpec(seed=1))
    return gpu, world, camera_of()


def camera_of():
    from sdfserver.render import Camera

    sx, sy, sz = SIZE
    return Camera.look_at((sx * 0.5, sy * 0.75, sz * 0.5 - 200.0), (sx * 0.5 + 600.0, sy * 0.3, sz * 0.5 + 900.0),
                          width=1280, height=720).validated()


def render(args) -> None:
    from sdfserver.render import Renderer

    gpu, world, camera = world_and_camera(args.device)
    renderer = Renderer(gpu)
    frame = renderer.render(world, camera)
    np.savez_compressed(args.out, pixels=frame.pixels)
    print(json.dumps({"device_ms": frame.device_ms, "out": args.out}))


def diff(args) -> None:
    a, b = np.load(args.a)["pixels"], np.load(args.b)["pixels"]
    differ = np.argwhere((a != b).any(axis=-1))  # (py, px)
    np.save(args.out, differ[:args.limit])
    print(json.dumps({"pixels": int(a.shape[0] * a.shape[1]), "differing": len(differ),
                      "fraction": len(differ) / (a.shape[0] * a.shape[1]), "kept": min(len(differ), args.limit)}))


def pick(args) -> None:
    from sdfserver.render import Renderer

    gpu, world, camera = world_and_camera(args.device)
    renderer = Renderer(gpu)
    hits = []
    for py, px in np.load(args.pixels):
        hit = renderer.pick(world, camera, px + 0.5, py + 0.5)
        hits.append((-1, -1, -1) if hit is None else tuple(hit.voxel))
    np.save(args.out, np.array(hits, dtype=np.int64).reshape(-1, 3))


def entry_exit(origin: np.ndarray, direction: np.ndarray, voxel: np.ndarray) -> tuple[float, float]:
    lo, hi = voxel.astype(np.float64), voxel.astype(np.float64) + 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (lo - origin) / direction, (hi - origin) / direction
    a = np.where(direction == 0, np.where((origin >= lo) & (origin < hi), -np.inf, np.inf), a)
    b = np.where(direction == 0, np.where((origin >= lo) & (origin < hi), np.inf, -np.inf), b)
    return float(np.minimum(a, b).max()), float(np.maximum(a, b).min())


def judge(args) -> None:
    camera = camera_of()
    pixels, first, second = np.load(args.pixels), np.load(args.hits_a), np.load(args.hits_b)
    counts = {"pixels": len(pixels), "a_off_ray": 0, "b_off_ray": 0, "a_missed": 0, "b_missed": 0,
              "a_miss_sky": 0, "b_miss_sky": 0, "same_voxel": 0, "grazed": 0}
    for (py, px), ha, hb in zip(pixels, first, second):
        origin, direction = (np.asarray(v, np.float64) for v in camera.ray(px + 0.5, py + 0.5))
        if (ha == hb).all():
            counts["same_voxel"] += 1  # same voxel, another face (a tie between axes)
            continue
        ta = entry_exit(origin, direction, ha) if ha[0] >= 0 else None
        tb = entry_exit(origin, direction, hb) if hb[0] >= 0 else None
        for name, t in (("a", ta), ("b", tb)):
            if t is not None and t[0] > t[1] + 1e-9:
                counts[f"{name}_off_ray"] += 1
        if ta is None or tb is None:
            counts["a_miss_sky" if ta is None else "b_miss_sky"] += 1
            continue
        if abs(ta[0] - tb[0]) < 1e-9 or min(ta[1] - ta[0], tb[1] - tb[0]) < 1e-9:
            counts["grazed"] += 1
        elif ta[0] > tb[0]:
            counts["a_missed"] += 1
        else:
            counts["b_missed"] += 1
    print(json.dumps(counts))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("render")
    p.add_argument("--out", required=True)
    p.add_argument("--device", default=None)
    p = sub.add_parser("diff")
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--out", required=True)
    p.add_argument("--limit", type=int, default=3000)
    p = sub.add_parser("pick")
    p.add_argument("--pixels", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--device", default=None)
    p = sub.add_parser("judge")
    p.add_argument("--pixels", required=True)
    p.add_argument("hits_a")
    p.add_argument("hits_b")
    args = parser.parse_args()
    {"render": render, "diff": diff, "pick": pick, "judge": judge}[args.what](args)


if __name__ == "__main__":
    main()
