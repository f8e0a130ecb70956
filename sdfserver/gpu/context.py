"""GpuContext: the single owner of an OpenCL context, its queue and its device memory.

Whoever holds a GpuContext owns the device: the engine thread in the server,
the test or the benchmark otherwise. The one exception is ``download_later``'s
``wait``, which any thread may call: it reads a private staging buffer on a queue
of its own. Buffers are allocated through
``allocate`` so that every byte is counted against the memory budget before
the driver is asked for it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np
import pyopencl as cl

from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.gpu.device import choose_device
from sdfserver.gpu.programs import ProgramCache, device_defines
from sdfserver.gpu.slots import SlotPools
from sdfserver.gpu.uploads import UploadRing, read_only_copy

# Leave room for the driver, programs and transient transfers.
DEFAULT_BUDGET_FRACTION = 0.85


class GpuContext:
    def __init__(self, device: cl.Device, memory_budget_bytes: int | None = None):
        self.device = device
        self.context = cl.Context([device])
        self.queue = cl.CommandQueue(
            self.context, properties=cl.command_queue_properties.PROFILING_ENABLE
        )
        # Device-to-host transfers that must not hold up the work queue (download_later).
        self.transfer_queue = cl.CommandQueue(self.context)
        self.uploads = UploadRing(self.context, self.queue)  # a step's brush records (engine thread)
        self.programs = ProgramCache(self.context, device_defines(device))
        device_bytes = int(device.global_mem_size)
        if memory_budget_bytes is None:
            memory_budget_bytes = int(device_bytes * DEFAULT_BUDGET_FRACTION)
        self.memory_budget_bytes = int(memory_budget_bytes)
        self.max_allocation_bytes = int(device.max_mem_alloc_size)
        self._allocated_bytes = 0
        self._lock = threading.Lock()
        self.slot_pools = SlotPools(self)  # small worlds side by side (gpu/slots.py)

    @classmethod
    def create(cls, device_spec: str | None = None, memory_budget_bytes: int | None = None):
        return cls(choose_device(device_spec), memory_budget_bytes)

    @property
    def device_name(self) -> str:
        return f"{self.device.platform.name.strip()} / {self.device.name.strip()}"

    @property
    def allocated_bytes(self) -> int:
        return self._allocated_bytes

    def check_fits(self, sizes_bytes: list[int], what: str) -> None:
        """Raise DeviceMemoryExceeded unless all of ``sizes_bytes`` fit now."""
        total = sum(sizes_bytes)
        largest = max(sizes_bytes, default=0)
        if largest > self.max_allocation_bytes:
            raise DeviceMemoryExceeded(
                f"{what} needs a {largest / 2**20:.0f} MiB buffer; the device allows at most "
                f"{self.max_allocation_bytes / 2**20:.0f} MiB in one buffer"
            )
        free = self.memory_budget_bytes - self._allocated_bytes
        if total > free:
            raise DeviceMemoryExceeded(
                f"{what} needs {total / 2**20:.0f} MiB of device memory; "
                f"{free / 2**20:.0f} MiB of the {self.memory_budget_bytes / 2**20:.0f} MiB "
                f"budget is free"
            )

    def allocate(self, nbytes: int) -> cl.Buffer:
        with self._lock:
            self.check_fits([nbytes], "buffer")
            buffer = cl.Buffer(self.context, cl.mem_flags.READ_WRITE, size=max(1, nbytes))
            self._allocated_bytes += nbytes
            return buffer

    def allocate_all(self, sizes: list[int]) -> list[cl.Buffer]:
        """A buffer of each size, or none: what was allocated before a failure is released."""
        allocated: list[cl.Buffer] = []
        try:
            for n in sizes:
                allocated.append(self.allocate(n))
        except BaseException:
            for buf, n in zip(allocated, sizes):
                self.release(buf, n)
            raise
        return allocated

    def release(self, buffer: cl.Buffer, nbytes: int) -> None:
        with self._lock:
            buffer.release()
            self._allocated_bytes -= nbytes

    def download_later(self, buffer: cl.Buffer, out: np.ndarray) -> Callable[[], None]:
        """Copy ``buffer`` as it will be once the work queued so far has run into ``out``,
        without holding up the work queue. Returns ``wait``; ``out`` is filled once it returns.

        Only a device-side copy into a staging buffer joins the work queue (microseconds);
        ``wait`` reads the staging buffer on the transfer queue, from the calling thread. A
        blocking read of a whole world on the work queue would hold every later kernel (and the
        engine thread) for as long as the transfer to pageable host memory takes."""
        nbytes = out.nbytes
        staging = self.allocate(nbytes)
        try:
            copied = cl.enqueue_copy(self.queue, staging, buffer, byte_count=nbytes)
            self.queue.flush()
        except BaseException:
            self.release(staging, nbytes)
            raise

        def wait() -> None:
            try:
                cl.enqueue_copy(self.transfer_queue, out, staging, wait_for=[copied], is_blocking=True)
            finally:
                self.release(staging, nbytes)

        return wait

    def upload(self, array: np.ndarray) -> cl.Buffer:
        """A short-lived read-only buffer (edit lists); not counted against the budget."""
        return read_only_copy(self.context, array)
