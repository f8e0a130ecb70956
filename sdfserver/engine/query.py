"""Point queries on the device: distance, colour and gradient direction at points.

A point ``(x, y, z)`` in voxel units falls in the voxel ``floor(p)``; a point
outside the world rejects the whole query. See ``kernels/query.cl`` for the
gradient.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.base import int4
from sdfserver.errors import InvalidInput
from sdfserver.world import World


@dataclass(frozen=True)
class QueryResult:
    version: int  # the world version the field reflects
    distances: np.ndarray  # (N,) uint8, capped Manhattan distance, 0 inside solids
    colours: np.ndarray  # (N,) uint8, the colour the field records at the voxel (0 in air)
    gradients: np.ndarray  # (N, 3) float32 unit vectors (x, y, z), zero where the field is flat


def voxel_points(points: np.ndarray, size: tuple[int, int, int]) -> np.ndarray:
    """(N, 3) finite coordinates -> (N, 4) int32 voxels; InvalidInput unless all lie in the world."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3 or points.dtype.kind not in "iuf":
        raise InvalidInput(f"points must be an (N, 3) numeric array, got {points.dtype} {points.shape}")
    if points.shape[0] == 0:
        raise InvalidInput("points must not be empty")
    coords = np.floor(points.astype(np.float64))
    if not np.isfinite(coords).all():
        raise InvalidInput("points must be finite numbers")
    outside = np.flatnonzero(((coords < 0) | (coords >= np.array(size))).any(axis=1))
    if outside.size:
        raise InvalidInput(f"point {points[outside[0]].tolist()} lies outside the world {list(size)} "
                           f"({outside.size} outside)")
    out = np.zeros((len(coords), 4), dtype=np.int32)
    out[:, :3] = coords
    return out


def query_points(world: World, points: np.ndarray) -> QueryResult:
    """Run on the thread that owns the world's GpuContext."""
    gpu = world.gpu
    voxels = voxel_points(points, world.config.size)
    n = len(voxels)
    points_buf = gpu.upload(voxels)
    packed_buf = cl.Buffer(gpu.context, cl.mem_flags.WRITE_ONLY, size=2 * n)
    gradient_buf = cl.Buffer(gpu.context, cl.mem_flags.WRITE_ONLY, size=16 * n)
    try:
        defines, field = world.field_source()
        gpu.programs.kernel("query.cl", "query_points", **defines)(
            gpu.queue, (-(-n // 64) * 64,), (64,), *field, int4(world.config.size),
            points_buf, np.int32(n), packed_buf, gradient_buf)
        packed = np.empty(n, dtype=np.uint16)
        gradients = np.empty((n, 4), dtype=np.float32)
        cl.enqueue_copy(gpu.queue, packed, packed_buf)
        cl.enqueue_copy(gpu.queue, gradients, gradient_buf, is_blocking=True)
    finally:
        for buf in (points_buf, packed_buf, gradient_buf):
            buf.release()
    return QueryResult(world.field_version, (packed >> 8).astype(np.uint8), (packed & 0xFF).astype(np.uint8),
                       np.ascontiguousarray(gradients[:, :3]))
