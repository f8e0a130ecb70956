"""Launches of kernels/bricks.cl: gather bricks into a dense box, classify a box's bricks,
scatter stored bricks back into the pools."""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.base import grid, int4
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext
from sdfserver.sparse.pool import BrickPool


class ClassifyResults:
    """The classification's two result buffers, kept from one recompute to the next (grown when a
    region has more bricks): allocating them for every brush cost more than the kernel."""

    def __init__(self, gpu: GpuContext):
        self.gpu = gpu
        self.capacity = 0
        self.mixed: cl.Buffer | None = None
        self.first: cl.Buffer | None = None

    def take(self, count: int) -> tuple[cl.Buffer, cl.Buffer]:
        if count > self.capacity:
            self.release()
            capacity = max(count, 2 * self.capacity, 64)
            flags = cl.mem_flags.READ_WRITE
            self.mixed = cl.Buffer(self.gpu.context, flags, size=4 * capacity)
            self.first = cl.Buffer(self.gpu.context, flags, size=4 * capacity)
            self.capacity = capacity
        return self.mixed, self.first

    def release(self) -> None:
        for buffer in (self.mixed, self.first):
            if buffer is not None:
                buffer.release()
        self.mixed = self.first = None
        self.capacity = 0


def _pool_args(pool: BrickPool, voxels: cl.Buffer, field: cl.Buffer) -> tuple:
    """POOL_ARGS: every segment's voxels and field buffers and the bricks a segment holds; with
    no segment, ``voxels`` and ``field`` stand in (no code names a slot then, so none is read)."""
    if not pool.segments:
        return (voxels,) * 4 + (field,) * 4 + (np.int32(pool.segment_bricks),)
    return (*pool.kernel_buffers("voxels"), *pool.kernel_buffers("field"), np.int32(pool.segment_bricks))


def gather(gpu: GpuContext, pool: BrickPool, bricks: Box, codes: np.ndarray, voxels: cl.Buffer,
           field: cl.Buffer, box: Box, cap: int, brick: int, defines: dict[str, int]) -> None:
    """Fill ``voxels`` and ``field`` (dense, extent ``box``) with the world's box ``box``;
    ``codes`` covers ``bricks``, the bricks ``box`` meets; ``defines``: the world's
    ``field_defines`` (what implicit bricks' values are)."""
    gsize, lsize = grid(box.shape_xyz)
    with gpu.uploads.staged(codes.astype(np.int32)) as staged:  # a fresh array: the write may run later
        gpu.programs.kernel("bricks.cl", "gather_bricks", **defines)(
            gpu.queue, gsize, lsize, *_pool_args(pool, voxels, field), staged, int4(bricks.lo),
            int4(bricks.shape_xyz), np.int32(brick), voxels, field, int4(box.shape_xyz), int4(box.lo),
            np.int32(cap))


def classify(gpu: GpuContext, voxels: cl.Buffer, field: cl.Buffer, dims: tuple[int, int, int], region: Box,
             cap: int, brick: int, results: ClassifyResults, defines: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """For the bricks of ``region`` (coordinates in the dense box of extent ``dims``, whole
    bricks): whether each is mixed, and its first voxel; (z, y, x) arrays. Waits for the device."""
    count = region.volume // brick ** 3
    mixed, first = results.take(count)
    cl.enqueue_fill_buffer(gpu.queue, mixed, np.int32(0), 0, 4 * count)  # small: never past 2^31
    gsize, lsize = grid(region.shape_xyz)
    gpu.programs.kernel("bricks.cl", "classify_bricks", **defines)(
        gpu.queue, gsize, lsize, voxels, field, int4(dims), int4(region.lo), int4(region.shape_xyz),
        np.int32(brick), np.int32(cap), mixed, first)
    shape = tuple(v // brick for v in region.shape_zyx)
    mixed_host = np.empty(shape, dtype=np.int32)
    first_host = np.empty(shape, dtype=np.int32)
    cl.enqueue_copy(gpu.queue, mixed_host, mixed)
    cl.enqueue_copy(gpu.queue, first_host, first, is_blocking=True)
    return mixed_host.astype(bool), first_host


def scatter(gpu: GpuContext, pool: BrickPool, voxels: cl.Buffer, field: cl.Buffer, box: Box, region: Box,
            bricks: Box, codes: np.ndarray, brick: int) -> None:
    """Write the stored bricks of ``region`` (world coordinates, whole bricks, inside the dense
    box ``box``) to their slots; ``codes`` covers ``bricks``, region's bricks."""
    if not (codes >= 0).any():
        return
    local = Box(tuple(r - b for r, b in zip(region.lo, box.lo)), tuple(r - b for r, b in zip(region.hi, box.lo)))
    gsize, lsize = grid(local.shape_xyz)
    with gpu.uploads.staged(codes.astype(np.int32)) as staged:  # a fresh array: the write may run later
        gpu.programs.kernel("bricks.cl", "scatter_bricks")(
            gpu.queue, gsize, lsize, voxels, field, int4(box.shape_xyz), int4(box.lo), int4(local.lo),
            int4(local.shape_xyz), staged, int4(bricks.lo), int4(bricks.shape_xyz), np.int32(brick),
            *_pool_args(pool, voxels, field))
