"""Lowering — a field after edits that only add solids (kernels/lower.cl).

Computes: for each edited box D, the capped L1 distance T to the solids inside D, and the field
min(old, T) wherever D is nearer than the cap; exact, since adding solids adds terms to the
minimum the field is and changes nothing else. Its work is the rounded octahedron within the cap
of D, not the cap-grown, chunk-snapped region the full transform rewrites (about a sixth of it).
A Euclidean world's three stages (kernels/edt.cl) are each a minimum too, so each is lowered the
same way and stays current for the next recompute (``lower_euclidean``).
Used by dense worlds without a sign, a focus or padded borders whose algorithm is ``exact``,
when every edit since the last recompute wrote solids (no erasing: a removed voxel can raise
distances, which only the full transform finds) and each box is small (``MAX_BOX_VOXELS``).
Scratch: a Manhattan world's ``work`` and ``work2``; a Euclidean world's ``work2`` and
``edt_stack`` (its ``work`` and ``edt_plane`` hold stages it keeps).
"""

from __future__ import annotations

import numpy as np

from sdfserver.algorithms.base import AlgorithmRun, WorldBuffers, grid, int4
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext

# Each output voxel reads D's extent along its stage's axis, so D stays small; past these the
# whole-region transform is cheaper.
MAX_BOX_VOXELS = 64 ** 3
MAX_BOXES = 16
# Work-items sharing one (x, y) column of the last stage: up to 2·cap + D's depth voxels each.
COLUMN_SHARES = 16


def lowering_boxes(boxes: list[Box]) -> list[Box] | None:
    """The boxes to lower, or None where lowering does not pay (many or large boxes)."""
    if len(boxes) > MAX_BOXES:
        lo = tuple(min(b.lo[a] for b in boxes) for a in range(3))
        hi = tuple(max(b.hi[a] for b in boxes) for a in range(3))
        boxes = [Box(lo, hi)]
    boxes = [b for b in boxes if not b.empty]
    if not boxes or any(b.volume > MAX_BOX_VOXELS for b in boxes):
        return None
    return boxes


def lower(gpu: GpuContext, buffers: WorldBuffers, boxes: list[Box], cap: int) -> AlgorithmRun:
    """Lower the field around each of ``boxes`` (world-clipped, from ``lowering_boxes``)."""
    kernel = gpu.programs.kernel
    world = Box.of_size(buffers.dims)
    dims, cap_arg = int4(buffers.dims), np.int32(cap)
    run = AlgorithmRun()
    for d in boxes:
        g = d.grow(cap).intersect(world)
        (dx, dy, dz), (gx, gy, _) = d.shape_xyz, g.shape_xyz
        d_lo, d_n, g_lo, g_n = int4(d.lo), int4(d.shape_xyz), int4(g.lo), int4(g.shape_xyz)
        run.events.append(kernel("lower.cl", "lower_x")(
            gpu.queue, *grid((gx, dy, dz)), buffers.voxels, buffers.work2, dims, d_lo, d_n, g_lo, g_n, cap_arg))
        run.events.append(kernel("lower.cl", "lower_y")(
            gpu.queue, *grid((gx, gy, dz)), buffers.work2, buffers.work, d_lo, d_n, g_lo, g_n, cap_arg))
        run.events.append(kernel("lower.cl", "lower_z")(
            gpu.queue, *grid((gx, gy, COLUMN_SHARES), (32, 4, 2)), buffers.work, buffers.voxels, buffers.field, dims,
            d_lo, d_n, g_lo, g_n, cap_arg))
    return run


def lower_euclidean(gpu: GpuContext, buffers: WorldBuffers, boxes: list[Box], cap: int) -> AlgorithmRun:
    """Lower a Euclidean world's line, plane and field around each of ``boxes``."""
    kernel = gpu.programs.kernel
    world = Box.of_size(buffers.dims)
    dims, cap_arg = int4(buffers.dims), np.int32(cap)
    run = AlgorithmRun()
    for d in boxes:
        g = d.grow(cap).intersect(world)
        (dx, dy, dz), (gx, gy, gz) = d.shape_xyz, g.shape_xyz
        d_lo, d_n, g_lo, g_n = int4(d.lo), int4(d.shape_xyz), int4(g.lo), int4(g.shape_xyz)
        run.events.append(kernel("lower.cl", "elower_x")(
            gpu.queue, *grid((gx, dy, dz)), buffers.voxels, buffers.work2, buffers.work, dims, d_lo, d_n, g_lo, g_n,
            cap_arg))
        run.events.append(kernel("lower.cl", "elower_z")(
            gpu.queue, *grid((gx, dy, gz)), buffers.work2, buffers.edt_stack, buffers.edt_plane, dims, d_lo, d_n,
            g_lo, g_n, cap_arg))
        run.events.append(kernel("lower.cl", "elower_y")(
            gpu.queue, *grid((gx, gz, COLUMN_SHARES), (32, 4, 2)), buffers.edt_stack, buffers.field, dims,
            d_lo, d_n, g_lo, g_n, cap_arg))
    return run
