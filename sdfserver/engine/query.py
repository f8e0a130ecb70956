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

import struct
import weakref
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.base import int4
from sdfserver.errors import InvalidInput
from sdfserver.incoming import short
from sdfserver.world import World, WorldConfig

KINDS = {"points": 3, "spheres": 4, "rays": 7}  # columns of each kind's rows
ANSWERS = {"points": ("distances", "gradients", "colours"), "spheres": ("clearances", "directions"),
           "rays": ("hits", "distances", "normals", "colours", "voxels")}
LOCAL = 64
PLACE = struct.Struct("<4f")  # the kernels' float4 place: (origin, voxel_size)


@dataclass(frozen=True)
class QueryResult:
    version: int  # the world version the field reflects
    arrays: dict[str, np.ndarray]  # ANSWERS[kind] -> (N,) or (N, 3) arrays


def checked_rows(kind: str, rows: np.ndarray) -> np.ndarray:
    """(N, KINDS[kind]) numbers; InvalidInput naming the field otherwise (values are checked later)."""
    if kind not in KINDS:
        raise InvalidInput(f"unknown query kind {short(kind)}; ask one of {', '.join(KINDS)}")
    rows = np.asarray(rows)
    width = KINDS[kind]
    if rows.ndim != 2 or rows.shape[1] != width or rows.dtype.kind not in "iuf":
        raise InvalidInput(f"{kind} must be an (N, {width}) numeric array, got {rows.dtype} {list(rows.shape)}")
    if rows.shape[0] == 0:
        raise InvalidInput(f"{kind} must not be empty")
    return rows


def first_row(kind: str, rows: np.ndarray, bad: np.ndarray, what: str) -> InvalidInput:
    """The error that names the first row where ``bad`` (N, k) holds."""
    flagged = np.flatnonzero(bad.reshape(len(rows), -1).any(axis=1))
    return InvalidInput(f"{kind}[{flagged[0]}] {what}: {rows[flagged[0]].tolist()} ({flagged.size} such rows)")


def device_rows(kind: str, rows: np.ndarray, config: WorldConfig) -> np.ndarray:
    """Checked rows as the kernel reads them, float32: points (N, 3) and spheres (N, 4) in world
    units as sent, rays (N, 8) in voxel coordinates (origin, max length; unit direction, 0).
    Whole-array passes over what the kernel will see; a row is looked for only once a check fails."""
    rows = checked_rows(kind, rows)
    if kind == "rays":
        return ray_rows(rows, config)
    out = np.ascontiguousarray(rows, dtype=np.float32)  # no copy for a float32 blob
    lo = np.asarray(config.origin)
    hi = lo + np.asarray(config.size) * config.voxel_size
    # A column's min and max are one fast pass each over a transposed copy (NaN fails the
    # comparison); strided columns or an elementwise comparison of rows of 3 cost several times
    # as much in NumPy.
    lo32, hi32 = lo.astype(np.float32), hi.astype(np.float32)
    columns = np.ascontiguousarray(out[:, :3].T)
    if not all(columns[k].min() >= lo32[k] and columns[k].max() < hi32[k] for k in range(3)):
        if not np.isfinite(out).all():
            raise first_row(kind, rows, ~np.isfinite(out), "holds NaN or an infinity")
        raise first_row(kind, rows, (out[:, :3] < lo32) | (out[:, :3] >= hi32),
                        f"lies outside the world's box {lo.tolist()}..{hi.tolist()} (world units)")
    if kind == "spheres" and not (out[:, 3].min() >= 0 and out[:, 3].max() < np.inf):
        radius = out[:, 3]
        raise first_row(kind, rows, ~((radius >= 0) & (radius < np.inf)), "has a negative radius, NaN or an infinity")
    return out


def ray_rows(rows: np.ndarray, config: WorldConfig) -> np.ndarray:
    if not np.isfinite(rows).all():
        raise first_row("rays", rows, ~np.isfinite(rows), "holds NaN or an infinity")
    direction = rows[:, 3:6].astype(np.float64)
    norm = np.sqrt((direction * direction).sum(axis=1))
    if not norm.all():
        raise first_row("rays", rows, norm == 0, "has a direction of length 0")
    if (rows[:, 6] < 0).any():
        raise first_row("rays", rows, rows[:, 6] < 0, "has a negative max_length")
    out = np.zeros((len(rows), 8), dtype=np.float32)
    out[:, :3] = (rows[:, :3] - np.asarray(config.origin)) / config.voxel_size
    out[:, 3] = rows[:, 6] / config.voxel_size
    out[:, 4:7] = direction / norm[:, None]
    if not np.isfinite(out).all():
        raise first_row("rays", rows, ~np.isfinite(out), "holds a number past float32's range")
    return out


class KeptBuffers:
    """A device's query input and output buffers, kept and grown as queries need: a buffer made
    for each query cost more host time than the query (NVIDIA's driver allocates it inside the
    launch that first uses it). At most max_query_points rows of the widest kind: a few MiB."""

    def __init__(self, gpu) -> None:
        self.gpu = gpu
        self.buffers: dict[str, cl.Buffer] = {}
        self.sizes: dict[str, int] = {}

    def get(self, name: str, flags, nbytes: int) -> cl.Buffer:
        if self.sizes.get(name, 0) < nbytes:
            old = self.buffers.pop(name, None)
            if old is not None:
                old.release()  # OpenCL frees it once the queued work using it is done
            size = max(nbytes, 2 * self.sizes.get(name, 0))
            self.buffers[name] = cl.Buffer(self.gpu.context, flags, size=size)
            self.sizes[name] = size
        return self.buffers[name]


KEPT: "weakref.WeakKeyDictionary[object, KeptBuffers]" = weakref.WeakKeyDictionary()


def run_query(world: World, kind: str, rows: np.ndarray) -> QueryResult:
    """Run on the thread that owns the world's GpuContext."""
    gpu, config = world.gpu, world.config
    inputs = device_rows(kind, rows, config)
    n = len(inputs)
    out_bytes = {"points": 17 * n, "spheres": 16 * n, "rays": 29 * n}[kind]
    kept = KEPT.get(gpu)
    if kept is None:
        kept = KEPT[gpu] = KeptBuffers(gpu)
    in_buf = kept.get("in", cl.mem_flags.READ_ONLY, inputs.nbytes)
    out_buf = kept.get("out", cl.mem_flags.WRITE_ONLY, out_bytes)
    cl.enqueue_copy(gpu.queue, in_buf, inputs, is_blocking=False)  # done before the download below
    defines, field = world.field_source()
    gpu.programs.kernel("query.cl", f"query_{kind}", **defines)(
        gpu.queue, (-(-n // LOCAL) * LOCAL,), (LOCAL,), *field, int4(config.size),
        PLACE.pack(*config.origin, config.voxel_size), in_buf, np.int32(n), out_buf)
    raw = np.empty(out_bytes, dtype=np.uint8)  # its own: the answer's arrays are views of it
    cl.enqueue_copy(gpu.queue, raw, out_buf, is_blocking=True)
    return QueryResult(world.field_version, answers(kind, raw, n))


def answers(kind: str, raw: np.ndarray, n: int) -> dict[str, np.ndarray]:
    """The kernel's output buffer (kernels/query.cl: whole arrays one after another) as named,
    contiguous views."""
    floats = raw[:16 * n].view(np.float32)
    distances, vectors = floats[:n], floats[n:].reshape(n, 3)
    if kind == "points":
        return {"distances": distances, "gradients": vectors, "colours": raw[16 * n:]}
    if kind == "spheres":
        return {"clearances": distances, "directions": vectors}
    colours = raw[28 * n:]
    return {"hits": colours > 0, "distances": distances, "normals": vectors,
            "colours": colours, "voxels": raw[16 * n:28 * n].view(np.int32).reshape(n, 3)}
