"""Brush packing: a batch's edits written into a world's voxel buffer on the device.

A voxels edit is a list of (x, y, z, colour) rows (later duplicates win); box and sphere edits
go one alone through its own kernel, or several together through ``fill_brushes``, their
records packed into one small buffer (a launch costs the host more than a brush costs the
device). Edits keep world coordinates; ``origin`` is the world position of the buffer's first
voxel (a dense world's buffer starts at 0, a sparse world's scratch box elsewhere), so a sphere
covers the same voxels whichever buffer it is written into."""

from __future__ import annotations

import struct

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.base import float4, grid, int4
from sdfserver.edits import BoxEdit, Edit, SphereEdit, VoxelsEdit
from sdfserver.geometry import Box, Vec3
from sdfserver.gpu import GpuContext
from sdfserver.gpu.launches import KernelCopies
from sdfserver.gpu.slots import Slot

WORLD_ORIGIN = bytes(16)  # int4(0, 0, 0): a dense world's buffer starts at the world's corner
NO_STRIDE = np.int64(0)  # one world's buffer: every brush writes it (kernels/edits.cl)
# Each work-item of fill_brushes checks the later brushes of its world in its launch; the launch
# counts its work-items in 32 bits.
BRUSHES_PER_LAUNCH = 256
WORK_ITEMS_PER_LAUNCH = 1 << 30
# The n brushes of a launch are first checked for brushes a later box hides whole (``visible``)
# when they cover more than this many voxels per pair of brushes, summed: the check's host time
# grows with the pairs, the launch's device time with the voxels, and past this the launch costs
# a GPU about what the check costs the host (a CPU device far more).
CULL_PER_PAIR_VOXELS = 4096
# A record: int4 (corner, colour), int4 (extent, first work-item), float4 (centre, radius²),
# int4 (slot, end of its world's brushes, 0, 0).
BRUSH_RECORD = struct.Struct("<8i4f2i8x")
FLOAT32_MAX = float(np.finfo(np.float32).max)  # struct refuses larger; any such sphere covers the world


def _launch(gpu: GpuContext, kernels: KernelCopies | None, name: str, global_size: tuple, local_size: tuple,
            *args) -> None:
    """One edits.cl kernel: the world's copy where it has them (``gpu/launches.py``)."""
    kernel = gpu.programs.kernel("edits.cl", name)
    if kernels is None:
        kernel(gpu.queue, global_size, local_size, *args)
    else:
        kernels.enqueue(gpu.queue, kernel, global_size, local_size, args)


def enqueue_voxels(gpu: GpuContext, voxels: cl.Buffer, dims: bytes, size: Vec3, e: VoxelsEdit,
                   origin: bytes = WORLD_ORIGIN, kernels: KernelCopies | None = None) -> None:
    # Later duplicates win: keep the last occurrence of each position.
    flat = np.ravel_multi_index(e.voxels[::-1, 2::-1].T, size[::-1])
    _, first = np.unique(flat, return_index=True)
    rows = e.voxels[::-1][first].astype(np.uint16)
    list_buf = gpu.upload(rows)
    n = len(rows)
    _launch(gpu, kernels, "set_voxels", (-(-n // 64) * 64,), (64,), voxels, dims, origin, list_buf, np.int32(n))
    list_buf.release()  # OpenCL frees it only once the queued kernel has finished


def enqueue_brushes(gpu: GpuContext, voxels: cl.Buffer, dims: bytes, brushes: list[tuple[Edit, Box]],
                    origin: bytes = WORLD_ORIGIN, kernels: KernelCopies | None = None) -> None:
    """Box and sphere edits, each with its clipped box: one alone with its own kernel, several
    with fill_brushes (their records in one small buffer). ``kernels``: the world's kernel
    copies, if it has them."""
    brushes = culled(brushes)
    if len(brushes) == 1:
        enqueue_brush(gpu, voxels, dims, *brushes[0], origin, kernels)
        return
    if not brushes:
        return
    records, first = brush_records([(0, brushes)])
    _launch_records(gpu, kernels, voxels, dims, origin, records, first, NO_STRIDE)


def brush_records(groups: list[tuple[int, list[tuple[Edit, Box]]]]) -> tuple[np.ndarray, int]:
    """fill_brushes's records (kernels/edits.cl) of each group's brushes, (slot, brushes) a world,
    in order, as (n, 16) int32; and the number of work-items they take."""
    # Packed with a struct a record: element-wise numpy stores cost 4x as much host time, and
    # building the array from lists of tuples about twice as much.
    packed, first, count = bytearray(), 0, 0
    for slot, brushes in groups:
        end = count + len(brushes)  # this world's brushes end there
        for edit, box in brushes:
            (x0, y0, z0), (x1, y1, z1) = box.lo, box.hi
            if type(edit) is SphereEdit:
                (cx, cy, cz), radius2 = edit.center, min(edit.radius * edit.radius, FLOAT32_MAX)
            else:
                cx = cy = cz = 0.0
                radius2 = -1.0  # a negative radius²: a box
            packed += BRUSH_RECORD.pack(x0, y0, z0, edit.colour, x1 - x0, y1 - y0, z1 - z0, first,
                                        cx, cy, cz, radius2, slot, end)
            first += (x1 - x0) * (y1 - y0) * (z1 - z0)
        count = end
    return np.frombuffer(packed, dtype=np.int32).reshape(-1, 16), first


def _launch_records(gpu: GpuContext, kernels: KernelCopies | None, voxels: cl.Buffer, dims: bytes, origin: bytes,
                    records: np.ndarray, total: int, voxel_stride: np.int64) -> None:
    local = 64
    with gpu.uploads.staged(records) as record_buf:
        _launch(gpu, kernels, "fill_brushes", (-(-total // local) * local,), (local,), voxels, dims, origin,
                record_buf, np.int32(len(records)), np.uint32(total), voxel_stride)


def enqueue_pooled_brushes(gpu: GpuContext, pooled: list[tuple[Slot, list[tuple[Edit, Box]]]]) -> None:
    """Each world's brushes in ``pooled`` (its slot, its last brushes, after every launch it
    made itself: ``World.apply_plans``) into its slot, one fill_brushes launch per pool for the
    worlds that fit one (BRUSHES_PER_LAUNCH brushes, WORK_ITEMS_PER_LAUNCH work-items)."""
    by_pool: dict[int, list] = {}
    for slot, brushes in pooled:
        brushes = culled(brushes)
        by_pool.setdefault(id(slot.pool), []).append((slot, brushes, sum(box.volume for _, box in brushes)))
    for members in by_pool.values():
        pool = members[0][0].pool
        dims, stride = int4(pool.dims), np.int64(pool.sizes[0])
        launches, group, count, items = [], [], 0, 0
        for slot, brushes, volume in members:
            if group and (count + len(brushes) > BRUSHES_PER_LAUNCH or items + volume > WORK_ITEMS_PER_LAUNCH):
                launches.append(group)
                group, count, items = [], 0, 0
            group.append((slot.index, brushes))
            count += len(brushes)
            items += volume
        launches.append(group)
        for group in launches:
            records, total = brush_records(group)
            _launch_records(gpu, pool.kernels, pool.voxels, dims, WORLD_ORIGIN, records, total, stride)


def culled(brushes: list[tuple[Edit, Box]]) -> list[tuple[Edit, Box]]:
    """``brushes``, less those a later box hides whole (``visible``) where they cover enough voxels
    for the check to pay (CULL_PER_PAIR_VOXELS)."""
    if len(brushes) > 1 and sum(box.volume for _, box in brushes) > CULL_PER_PAIR_VOXELS * len(brushes) ** 2:
        return visible(brushes)
    return brushes


def visible(brushes: list[tuple[Edit, Box]]) -> list[tuple[Edit, Box]]:
    """``brushes`` less those a later box covers whole: a later brush wins where they overlap, so
    those would write nothing (fill_brushes would still visit each of their voxels). Vectorised:
    a launch holds at most a few hundred brushes."""
    lo = np.array([box.lo for _, box in brushes]).T  # (3, n)
    hi = np.array([box.hi for _, box in brushes]).T
    # covers[i, j]: brush j is a box holding brush i's whole box
    n = len(brushes)
    is_box = np.array([type(edit) is BoxEdit for edit, _ in brushes])
    covers = np.triu(np.broadcast_to(is_box, (n, n)), k=1)  # j > i: a later box
    for axis in range(3):
        covers &= lo[axis][None, :] <= lo[axis][:, None]
        covers &= hi[axis][:, None] <= hi[axis][None, :]
    hidden = covers.any(axis=1)
    return [b for b, h in zip(brushes, hidden.tolist()) if not h]


def enqueue_brush(gpu: GpuContext, voxels: cl.Buffer, dims: bytes, e: Edit, box: Box,
                  origin: bytes = WORLD_ORIGIN, kernels: KernelCopies | None = None) -> None:
    gsize, lsize = grid(box.shape_xyz)
    if isinstance(e, BoxEdit):
        _launch(gpu, kernels, "fill_box", gsize, lsize, voxels, dims, origin, int4(box.lo), int4(box.shape_xyz),
                np.uint32(e.colour))
    elif isinstance(e, SphereEdit):
        _launch(gpu, kernels, "fill_sphere", gsize, lsize, voxels, dims, origin, int4(box.lo), int4(box.shape_xyz),
                float4(e.center), np.float32(e.radius * e.radius), np.uint32(e.colour))
