"""Collision and navigation queries on the device, in world units: points, spheres and rays.

One request asks one kind, as rows of float numbers (``KINDS``: the columns of each):

- ``points`` (x, y, z) -> ``distances``: the field's signed distance (world units) trilinearly
  interpolated between voxel centres, ``gradients``: the interpolant's gradient (d distance / d
  world unit, not normalised), ``colours``: the value of the voxel holding the point;
- ``spheres`` (x, y, z, r) -> ``clearances``: the distance at the centre minus r, ``directions``:
  the unit gradient there (the way out of collision; zero where the field is flat);
- ``rays`` (ox, oy, oz, dx, dy, dz, max_length) -> per ray ``hits``, ``distances`` (t along the
  normalised direction to the first solid voxel; a miss: max_length), ``normals`` (the entered
  face's, zero for a ray that starts in a solid or misses), ``colours``, ``voxels`` (-1 on a miss).

World unit w lies at voxel coordinate (w - origin) / voxel_size; voxel v spans [v, v + 1). Points
and sphere centres must lie in the world's box; rays may start anywhere and are clipped to it.
Every check happens here, before anything runs, and names the field (``InvalidInput``: 422).
One upload, one kernel launch and one download a query (``kernels/query.cl``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.base import int4
from sdfserver.errors import InvalidInput
from sdfserver.world import World, WorldConfig

KINDS = {"points": 3, "spheres": 4, "rays": 7}  # columns of each kind's rows
ANSWERS = {"points": ("distances", "gradients", "colours"), "spheres": ("clearances", "directions"),
           "rays": ("hits", "distances", "normals", "colours", "voxels")}
LOCAL = 64


@dataclass(frozen=True)
class QueryResult:
    version: int  # the world version the field reflects
    arrays: dict[str, np.ndarray]  # ANSWERS[kind] -> (N,) or (N, 3) arrays


def checked_rows(kind: str, rows: np.ndarray) -> np.ndarray:
    """(N, KINDS[kind]) finite numbers as float64; InvalidInput naming the field otherwise."""
    if kind not in KINDS:
        raise InvalidInput(f"unknown query kind {kind!r}; ask one of {', '.join(KINDS)}")
    rows = np.asarray(rows)
    width = KINDS[kind]
    if rows.ndim != 2 or rows.shape[1] != width or rows.dtype.kind not in "iuf":
        raise InvalidInput(f"{kind} must be an (N, {width}) numeric array, got {rows.dtype} {list(rows.shape)}")
    if rows.shape[0] == 0:
        raise InvalidInput(f"{kind} must not be empty")
    rows = rows.astype(np.float64, copy=False)
    bad = np.flatnonzero(~np.isfinite(rows).all(axis=1))
    if bad.size:
        raise InvalidInput(f"{kind}[{bad[0]}] holds NaN or an infinity ({bad.size} such rows)")
    return rows


def voxel_coordinates(kind: str, xyz: np.ndarray, config: WorldConfig) -> np.ndarray:
    """World units -> voxel coordinates, each inside the world's box [0, size)."""
    v = (xyz - np.asarray(config.origin)) / config.voxel_size
    outside = np.flatnonzero(((v < 0) | (v >= np.asarray(config.size))).any(axis=1))
    if outside.size:
        lo = np.asarray(config.origin)
        hi = lo + np.asarray(config.size) * config.voxel_size
        raise InvalidInput(f"{kind}[{outside[0]}] at {xyz[outside[0]].tolist()} lies outside the world's box "
                           f"{lo.tolist()}..{hi.tolist()} (world units; {outside.size} outside)")
    return v


def device_rows(kind: str, rows: np.ndarray, config: WorldConfig) -> np.ndarray:
    """Checked rows as the kernel reads them: float32, one float4 a point or sphere, two a ray."""
    rows = checked_rows(kind, rows)
    n = len(rows)
    if kind == "rays":
        out = np.zeros((n, 8), dtype=np.float32)
        direction, max_length = rows[:, 3:6], rows[:, 6]
        norm = np.linalg.norm(direction, axis=1)
        for name, bad in (("direction of length 0", norm == 0), ("negative max_length", max_length < 0)):
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise InvalidInput(f"rays[{i}] has a {name}: {rows[i].tolist()}")
        out[:, :3] = (rows[:, :3] - np.asarray(config.origin)) / config.voxel_size
        out[:, 3] = max_length / config.voxel_size
        out[:, 4:7] = direction / norm[:, None]
        return out
    out = np.zeros((n, 4), dtype=np.float32)
    out[:, :3] = voxel_coordinates(kind, rows[:, :3], config)
    if kind == "spheres":
        negative = np.flatnonzero(rows[:, 3] < 0)
        if negative.size:
            raise InvalidInput(f"spheres[{negative[0]}] has a negative radius: {rows[negative[0]].tolist()}")
        out[:, 3] = rows[:, 3]
    return out


def run_query(world: World, kind: str, rows: np.ndarray) -> QueryResult:
    """Run on the thread that owns the world's GpuContext."""
    gpu, config = world.gpu, world.config
    inputs = device_rows(kind, rows, config)
    n = len(inputs)
    out_bytes = 16 * n + (16 * n if kind == "rays" else n if kind == "points" else 0)
    in_buf = gpu.upload(inputs)
    out_buf = cl.Buffer(gpu.context, cl.mem_flags.WRITE_ONLY, size=out_bytes)
    try:
        defines, field = world.field_source()
        gpu.programs.kernel("query.cl", f"query_{kind}", **defines)(
            gpu.queue, (-(-n // LOCAL) * LOCAL,), (LOCAL,), *field, int4(config.size),
            np.float32(config.voxel_size), in_buf, np.int32(n), out_buf)
        raw = np.empty(out_bytes, dtype=np.uint8)
        cl.enqueue_copy(gpu.queue, raw, out_buf, is_blocking=True)
    finally:
        in_buf.release()
        out_buf.release()
    return QueryResult(world.field_version, answers(kind, raw, n))


def answers(kind: str, raw: np.ndarray, n: int) -> dict[str, np.ndarray]:
    """The kernel's output buffer (see kernels/query.cl) as named arrays."""
    head = raw[:16 * n].view(np.float32).reshape(n, 4)
    if kind == "points":
        return {"distances": head[:, 3], "gradients": head[:, :3], "colours": raw[16 * n:]}
    if kind == "spheres":
        return {"clearances": head[:, 3], "directions": head[:, :3]}
    hits = raw[16 * n:].view(np.int32).reshape(n, 4)
    return {"hits": hits[:, 3] > 0, "distances": head[:, 3], "normals": head[:, :3],
            "colours": hits[:, 3].astype(np.uint8), "voxels": hits[:, :3]}


def query_points(world: World, points: np.ndarray) -> QueryResult:
    return run_query(world, "points", points)
