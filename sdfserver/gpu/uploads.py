"""Small read-only uploads (a step's brush records) through a few device buffers that are kept.

A buffer made with its data (``read_only_copy``, ``GpuContext.upload``) costs little to make,
but NVIDIA's driver allocates and fills it inside the first kernel launch that uses it: that
launch was the largest host cost of an engine step under load (12% of the server process's GIL
samples), and a kept buffer filled by a non-blocking write cut the host time of applying a
16-brush step by 18-55% (docs/benchmarks.md). A slot is
written again only once its last write has completed; the queue is in order, so the kernels
that read the old contents have run by the time the new write does. When every slot is still
in flight, or the array is too large, it falls back to a buffer of its own.
"""

from __future__ import annotations

import contextlib
from typing import Iterator

import numpy as np
import pyopencl as cl

COMPLETE = cl.command_execution_status.COMPLETE


def read_only_copy(context: cl.Context, array: np.ndarray) -> cl.Buffer:
    """A buffer of its own made with ``array``'s data; the caller releases it."""
    return cl.Buffer(context, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(array))


class UploadRing:
    def __init__(self, context: cl.Context, queue: cl.CommandQueue, slot_bytes: int = 16 << 10, slots: int = 8):
        self.context, self.queue, self.slot_bytes = context, queue, slot_bytes
        self._buffers: list[cl.Buffer | None] = [None] * slots
        self._writes: list[cl.Event | None] = [None] * slots
        self._next = 0
        self.fallbacks = 0  # uploads that took a buffer of their own

    @contextlib.contextmanager
    def staged(self, array: np.ndarray) -> Iterator[cl.Buffer]:
        """A device copy of ``array`` for the kernels enqueued inside the block (engine thread).
        The write may run later: ``array`` must not change afterwards (pass a fresh one)."""
        array = np.ascontiguousarray(array)
        slot = self._free_slot() if array.nbytes <= self.slot_bytes else None
        if slot is None:
            self.fallbacks += 1
            own = read_only_copy(self.context, array)
            try:
                yield own
            finally:
                own.release()  # OpenCL frees it once the kernels queued with it have run
            return
        buffer = self._buffers[slot]
        if buffer is None:
            buffer = self._buffers[slot] = cl.Buffer(self.context, cl.mem_flags.READ_ONLY, self.slot_bytes)
        # pyopencl keeps ``array`` alive until this write completes (the event's wait)
        self._writes[slot] = cl.enqueue_copy(self.queue, buffer, array, is_blocking=False)
        yield buffer

    def _free_slot(self) -> int | None:
        for _ in range(len(self._buffers)):
            slot = self._next
            self._next = (slot + 1) % len(self._buffers)
            write = self._writes[slot]
            if write is None:
                return slot
            if write.command_execution_status == COMPLETE:
                write.wait()  # at once: it has completed; lets go of the host array
                self._writes[slot] = None
                return slot
        return None
