"""Lowering — a field after edits that only add solids (kernels/lower.cl).

Computes: for each edited box D, the capped L1 distance T to the solids inside D, and the field
min(old, T) wherever D is nearer than the cap; exact, since adding solids adds terms to the
minimum the field is and changes nothing else. Its work is the rounded octahedron within the cap
of D, not the cap-grown, chunk-snapped region the full transform rewrites (about a sixth of it).
A Euclidean world's three stages (kernels/edt.cl) are each a minimum too, so each is lowered the
same way and stays current for the next recompute (``lower(..., euclidean=True)``).
Each Manhattan stage costs O(1) an output whatever the box's size (the sweeps of kernels/lower.cl);
a Euclidean world's reads the box's extent along its axis for each output.
Used by dense worlds without a sign, a focus or padded borders whose algorithm is ``exact``,
when each edited box is small enough (``MAX_BOX_VOXELS``; in a batch that erased,
``MAX_ERASING_BOX_VOXELS``; in a Euclidean world, ``MAX_EUCLIDEAN_BOX_VOXELS``). Where an edit
erased (a removed solid can raise distances) a Manhattan world first transforms only the box of
the voxels whose nearest solid may have been removed (``raise_bounds``), then lowers around what
was added; a Euclidean world whose batches only erased runs its incremental transform with that
box as the last stage's, and one that erased and added runs it whole.
Scratch: a Manhattan world's ``work`` and ``work2``; a Euclidean world's ``work2`` and
``edt_stack`` (its ``work`` and ``edt_plane`` hold stages it keeps).
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.base import AlgorithmRun, WorldBuffers, grid, int4
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext

# Lowering a box costs about its cap-grown octahedron and the transform its cap-grown box, so
# lowering pays for large boxes too; past MAX_BOX_VOXELS (as far as that was timed) boxes take the
# transform. A batch that erased first transforms the box where the field can rise, which can be
# nearly the whole region after reducing it on the device: past MAX_ERASING_BOX_VOXELS that costs
# more than the region's transform. A Euclidean world's stages read the box's extent along their
# axis for each output, so its boxes stay small.
MAX_BOX_VOXELS = 256 ** 3
MAX_ERASING_BOX_VOXELS = 200 ** 3
MAX_EUCLIDEAN_BOX_VOXELS = 64 ** 3
MAX_BOXES = 16
# Lowering pays where it spares the device a large transform; under this many voxels of regions
# the transform's few launches (prepared once, replayed while its regions repeat) cost the engine
# thread less than three launches per box and, where a batch erased, a wait for raise_bounds.
LOWER_ABOVE_REGION_VOXELS = 1 << 24
# Work-items sharing one line of lower_y or lower_z, or one (x, y) column of raise_bounds (a
# thread walking a long column alone is bound by latency, not bandwidth). A share of lower_y or
# lower_z first reads the rest of the box's depth, so it takes at least SHARE_DEPTHS times that
# depth in outputs, and at least SHARE_MIN_VOX.
COLUMN_SHARES = 16
SHARE_DEPTHS = 3
SHARE_MIN_VOX = 64
# lower_x's work-group, the lanes sharing one row (ROW_LANES in kernels/lower.cl).
ROW_LANES = 64


def lowering_boxes(boxes: list[Box], regions: list[Box], euclidean: bool = False,
                   erased: bool = False) -> list[Box] | None:
    """The boxes to lower, or None where lowering does not pay: many or large boxes (``euclidean``:
    a Euclidean world's; ``erased``: a batch that erased), or a transform of ``regions`` (what the
    recompute would rewrite instead) small enough to run as it is."""
    if sum(r.volume for r in regions) <= LOWER_ABOVE_REGION_VOXELS:
        return None
    if len(boxes) > MAX_BOXES:
        lo = tuple(min(b.lo[a] for b in boxes) for a in range(3))
        hi = tuple(max(b.hi[a] for b in boxes) for a in range(3))
        boxes = [Box(lo, hi)]
    boxes = [b for b in boxes if not b.empty]
    limit = MAX_EUCLIDEAN_BOX_VOXELS if euclidean else MAX_ERASING_BOX_VOXELS if erased else MAX_BOX_VOXELS
    if not boxes or any(b.volume > limit for b in boxes):
        return None
    return boxes


def lower(gpu: GpuContext, buffers: WorldBuffers, boxes: list[Box], cap: int, euclidean: bool = False) -> AlgorithmRun:
    """Lower the field around each of ``boxes`` (world-clipped, from ``lowering_boxes``); with
    ``euclidean``, a Euclidean world's line, plane and field."""
    kernel = gpu.programs.kernel
    world = Box.of_size(buffers.dims)
    dims, cap_arg = int4(buffers.dims), np.int32(cap)
    b = buffers
    run = AlgorithmRun()
    for d in boxes:
        g = d.grow(cap).intersect(world)
        (_, dy, dz), (gx, gy, gz) = d.shape_xyz, g.shape_xyz
        box = (int4(d.lo), int4(d.shape_xyz), int4(g.lo), int4(g.shape_xyz), cap_arg)
        if euclidean:
            stages = (("elower_x", (b.voxels, b.work2, b.work, dims)),
                      ("elower_z", (b.work2, b.edt_stack, b.edt_plane, dims)),
                      ("elower_y", (b.edt_stack, b.field, dims)))
            sizes = (grid((gx, dy, dz)), grid((gx, dy, gz)), grid((gx, gz, COLUMN_SHARES), (32, 4, 2)))
        else:
            stages = (("lower_x", (b.voxels, b.work2, dims)),
                      ("lower_y", (b.work2, b.work)),
                      ("lower_z", (b.work, b.work2, b.voxels, b.field, dims)))
            sizes = (((ROW_LANES, dy, dz), (ROW_LANES, 1, 1)),
                     grid((gx, dz, shares(gy, dy)), (32, 4, 2)),
                     grid((gx, gy, shares(gz, dz)), (32, 4, 2)))
        for (name, args), size in zip(stages, sizes):
            run.events.append(kernel("lower.cl", name)(gpu.queue, *size, *args, *box))
    return run


def shares(line_vox: int, depth_vox: int) -> int:
    """Work-items for each line of ``line_vox`` outputs through a box ``depth_vox`` deep."""
    return max(1, min(COLUMN_SHARES, -(-line_vox // max(SHARE_DEPTHS * depth_vox, SHARE_MIN_VOX))))


def raise_bounds(gpu: GpuContext, buffers: WorldBuffers, boxes: list[Box], cap: int, run: AlgorithmRun,
                 euclidean: bool = False) -> Box | None:
    """The box where removing solids from ``boxes`` can raise the field (every voxel whose nearest
    solid may have been removed), or None where none can; waits for the device. A transform of
    that box seeded from the field around it is exact: nothing outside it changes."""
    far = np.iinfo(np.int32).max
    bounds = np.array([far] * 3 + [-far] * 3, dtype=np.int32)
    buffer = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=bounds)
    try:
        world = Box.of_size(buffers.dims)
        for d in boxes:
            g = d.grow(cap).intersect(world)
            gx, gy, _ = g.shape_xyz
            run.events.append(gpu.programs.kernel("lower.cl", "raise_bounds")(
                gpu.queue, *grid((gx, gy, COLUMN_SHARES), (32, 4, 2)), buffers.field, int4(buffers.dims),
                int4(d.lo), int4(d.shape_xyz), int4(g.lo), int4(g.shape_xyz), np.int32(cap),
                np.int32(euclidean), buffer))
        cl.enqueue_copy(gpu.queue, bounds, buffer)
    finally:
        buffer.release()
    if bounds[0] > bounds[3]:
        return None
    return Box(tuple(int(v) for v in bounds[:3]), tuple(int(v) + 1 for v in bounds[3:]))
