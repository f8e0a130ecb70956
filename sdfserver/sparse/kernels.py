"""Launches of kernels/bricks.cl: gather bricks into a dense box, classify a box's bricks,
scatter stored bricks back into the pools."""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.base import grid, int4
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext
from sdfserver.sparse.pool import BrickPool


class _Codes:
    """A box of brick codes uploaded for one launch (released once the launch has run)."""

    def __init__(self, gpu: GpuContext, bricks: Box, codes: np.ndarray):
        self.lo, self.n = int4(bricks.lo), int4(bricks.shape_xyz)
        self.buffer = gpu.upload(np.ascontiguousarray(codes, dtype=np.int32))


def _pool_args(pool: BrickPool, voxels: cl.Buffer, field: cl.Buffer) -> tuple:
    """POOL_ARGS: every segment's voxels and field buffers and the bricks a segment holds; with
    no segment, ``voxels`` and ``field`` stand in (no code names a slot then, so none is read)."""
    if not pool.segments:
        return (voxels,) * 4 + (field,) * 4 + (np.int32(pool.segment_bricks),)
    return (*pool.kernel_buffers("voxels"), *pool.kernel_buffers("field"), np.int32(pool.segment_bricks))


def gather(gpu: GpuContext, pool: BrickPool, bricks: Box, codes: np.ndarray, voxels: cl.Buffer,
           field: cl.Buffer, box: Box, cap: int, brick: int) -> None:
    """Fill ``voxels`` and ``field`` (dense, extent ``box``) with the world's box ``box``;
    ``codes`` covers ``bricks``, the bricks ``box`` meets."""
    c = _Codes(gpu, bricks, codes)
    gsize, lsize = grid(box.shape_xyz)
    gpu.programs.kernel("bricks.cl", "gather_bricks")(
        gpu.queue, gsize, lsize, *_pool_args(pool, voxels, field), c.buffer, c.lo, c.n, np.int32(brick),
        voxels, field, int4(box.shape_xyz), int4(box.lo), np.int32(cap))
    c.buffer.release()  # freed by OpenCL once the launch has run


def classify(gpu: GpuContext, voxels: cl.Buffer, field: cl.Buffer, dims: tuple[int, int, int], region: Box,
             cap: int, brick: int) -> tuple[np.ndarray, np.ndarray]:
    """For the bricks of ``region`` (coordinates in the dense box of extent ``dims``, whole
    bricks): whether each is mixed, and its first voxel; (z, y, x) arrays. Waits for the device."""
    count = region.volume // brick ** 3
    mixed = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE, size=4 * count)
    first = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE, size=4 * count)
    try:
        cl.enqueue_fill_buffer(gpu.queue, mixed, np.int32(0), 0, 4 * count)  # small: never past 2^31
        gsize, lsize = grid(region.shape_xyz)
        gpu.programs.kernel("bricks.cl", "classify_bricks")(
            gpu.queue, gsize, lsize, voxels, field, int4(dims), int4(region.lo), int4(region.shape_xyz),
            np.int32(brick), np.int32(cap), mixed, first)
        shape = tuple(v // brick for v in region.shape_zyx)
        mixed_host = np.empty(shape, dtype=np.int32)
        first_host = np.empty(shape, dtype=np.int32)
        cl.enqueue_copy(gpu.queue, mixed_host, mixed)
        cl.enqueue_copy(gpu.queue, first_host, first, is_blocking=True)
    finally:
        mixed.release()
        first.release()
    return mixed_host.astype(bool), first_host


def scatter(gpu: GpuContext, pool: BrickPool, voxels: cl.Buffer, field: cl.Buffer, box: Box, region: Box,
            bricks: Box, codes: np.ndarray, brick: int) -> None:
    """Write the stored bricks of ``region`` (world coordinates, whole bricks, inside the dense
    box ``box``) to their slots; ``codes`` covers ``bricks``, region's bricks."""
    if not (codes >= 0).any():
        return
    c = _Codes(gpu, bricks, codes)
    local = Box(tuple(r - b for r, b in zip(region.lo, box.lo)), tuple(r - b for r, b in zip(region.hi, box.lo)))
    gsize, lsize = grid(local.shape_xyz)
    gpu.programs.kernel("bricks.cl", "scatter_bricks")(
        gpu.queue, gsize, lsize, voxels, field, int4(box.shape_xyz), int4(box.lo), int4(local.lo),
        int4(local.shape_xyz), c.buffer, c.lo, c.n, np.int32(brick), *_pool_args(pool, voxels, field))
    c.buffer.release()
