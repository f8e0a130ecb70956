"""Whole-buffer work on world-sized device buffers: fills, copies and host transfers.

A world's buffers reach 2^33 elements. Fills and device-to-device copies run as the
project's own kernels (``kernels/bulk.cl``), which count elements in 64 bits, never as
the driver's fill or copy: NVIDIA's fill counts in 32 bits and, past 2^31 elements, faults
the context or leaves the rest unwritten. Host transfers go in pieces of at most
``TRANSFER_PIECE_BYTES``, so no single driver transfer is larger than one that is known to
work. Everything here is enqueued on the context's work queue and runs on the thread that
owns it, except the ``wait`` that ``download_later`` returns.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pyopencl as cl

from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext

LOCAL_SIZE = 64
# Work-items of one fill or copy launch: enough to keep a large GPU busy; each loops
# over the elements past the first LOOP_WORK_ITEMS.
LOOP_WORK_ITEMS = 1 << 20
TRANSFER_PIECE_BYTES = 1 << 30
_ELEMENTS = {np.dtype(np.uint8): "uchar", np.dtype(np.uint16): "ushort", np.dtype(np.int32): "int"}


def _element(dtype) -> str:
    try:
        return _ELEMENTS[np.dtype(dtype)]
    except KeyError:
        raise TypeError(f"no bulk kernel for {np.dtype(dtype)}; one of {sorted(map(str, _ELEMENTS))}") from None


def _global_size(count: int, work_items: int) -> tuple[int]:
    items = min(max(1, count), max(1, work_items))
    return (-(-items // LOCAL_SIZE) * LOCAL_SIZE,)


def fill(gpu: GpuContext, buffer: cl.Buffer, dtype, value: int, count: int,
         work_items: int = LOOP_WORK_ITEMS) -> cl.Event:
    """Set the first ``count`` elements of ``buffer`` (of ``dtype``) to ``value``."""
    element = np.dtype(dtype)
    kernel = gpu.programs.kernel("bulk.cl", "fill", ELEMENT=_element(element))
    return kernel(gpu.queue, _global_size(count, work_items), (LOCAL_SIZE,), buffer, np.uint64(count),
                  element.type(value))


def copy(gpu: GpuContext, dst: cl.Buffer, src: cl.Buffer, dtype, count: int, dst_first: int = 0,
         src_first: int = 0, work_items: int = LOOP_WORK_ITEMS) -> cl.Event:
    """``dst[dst_first + i] = src[src_first + i]`` for ``i < count``, in elements of ``dtype``;
    the two ranges must not overlap."""
    kernel = gpu.programs.kernel("bulk.cl", "copy", ELEMENT=_element(dtype))
    return kernel(gpu.queue, _global_size(count, work_items), (LOCAL_SIZE,), dst, np.uint64(dst_first),
                  src, np.uint64(src_first), np.uint64(count))


def _pieces(nbytes: int, piece_bytes: int):
    for first in range(0, nbytes, piece_bytes):
        yield first, min(nbytes, first + piece_bytes)


def write(gpu: GpuContext, buffer: cl.Buffer, array: np.ndarray,
          piece_bytes: int = TRANSFER_PIECE_BYTES) -> None:
    """Copy a host array to the start of ``buffer``, in pieces; returns once it is on the device."""
    flat = np.ascontiguousarray(array).reshape(-1).view(np.uint8)
    for first, end in _pieces(flat.nbytes, piece_bytes):
        cl.enqueue_copy(gpu.queue, buffer, flat[first:end], dst_offset=first, is_blocking=False)
    gpu.queue.finish()


def read_box(gpu: GpuContext, buffer: cl.Buffer, dtype, dims: tuple[int, int, int], box: Box,
             piece_bytes: int = TRANSFER_PIECE_BYTES) -> np.ndarray:
    """The ``box`` of a world-sized (z, y, x) array of ``dtype`` and extent ``dims``, read in
    slabs of whole z-planes of at most ``piece_bytes`` (at least one plane).

    The last slab's copy blocks: the queue is in order, so it returns once every slab (and
    all work queued before) is done, which is cheaper than a separate ``queue.finish()``."""
    itemsize = np.dtype(dtype).itemsize
    out = np.empty(box.shape_zyx, dtype=dtype)
    sx, sy, _ = dims
    (x0, y0, z0), (nx, ny, nz) = box.lo, box.shape_xyz
    planes = max(1, piece_bytes // (nx * ny * itemsize))
    for k in range(0, nz, planes):
        slab = out[k:k + planes]
        cl.enqueue_copy(
            gpu.queue, slab, buffer,
            buffer_origin=(x0 * itemsize, y0, z0 + k), host_origin=(0, 0, 0),
            region=(nx * itemsize, ny, slab.shape[0]),
            buffer_pitches=(sx * itemsize, sx * sy * itemsize),
            host_pitches=(nx * itemsize, nx * ny * itemsize),
            is_blocking=k + planes >= nz,
        )
    return out


def download_later(gpu: GpuContext, buffer: cl.Buffer, out: np.ndarray,
                   piece_bytes: int = TRANSFER_PIECE_BYTES) -> Callable[[], None]:
    """Copy ``buffer`` as it will be once the work queued so far has run into ``out``, without
    holding up the work queue; returns ``wait``, after which ``out`` is filled (any thread may
    call it).

    Only a copy into a staging buffer, by ``copy``'s kernel, joins the work queue; ``wait``
    reads the staging buffer in pieces on the context's transfer queue."""
    nbytes = out.nbytes
    staging = gpu.allocate(nbytes)
    try:
        copied = copy(gpu, staging, buffer, np.uint8, nbytes)
        gpu.queue.flush()
    except BaseException:
        gpu.release(staging, nbytes)
        raise
    flat = out.reshape(-1).view(np.uint8)

    def wait() -> None:
        try:
            for first, end in _pieces(nbytes, piece_bytes):
                cl.enqueue_copy(gpu.transfer_queue, flat[first:end], staging, src_offset=first,
                                wait_for=[copied], is_blocking=False)
            gpu.transfer_queue.finish()
        finally:
            gpu.release(staging, nbytes)

    return wait
