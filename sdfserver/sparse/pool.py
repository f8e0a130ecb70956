"""A sparse world's brick pools on the device: one uchar and one ushort buffer of ``capacity``
bricks (voxels, packed field: 3 bytes a stored voxel), and the free slots.

The pools grow geometrically inside the memory budget: a pair half again as large (or as large
as fits) is allocated (checked first: DeviceMemoryExceeded and nothing changed when it does not
fit), the stored bricks copied over, the old pair released. A growth copies every stored brick
once, so its cost follows the stored bricks, not the world, and growing by a fraction keeps that
to a constant per brick over time; an edit that makes the pools grow waits for that copy. Each
pool is one buffer, so the device's largest buffer (a quarter of its memory on NVIDIA's OpenCL)
bounds the field pool. Slots are reserved before a batch is accepted (``reserve``), so a
recompute never runs out halfway."""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from sdfserver import bulk
from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.gpu import GpuContext

BYTES_PER_STORED_VOXEL = 3  # voxel uchar + field ushort
FIRST_CAPACITY_BRICKS = 64
# What a shrink keeps free, of the stored bricks: edits after a generator rarely grow the pools
# (a growth copies them), at 0.375 bytes a stored voxel.
SHRINK_HEADROOM = 0.125


class BrickPool:
    def __init__(self, gpu: GpuContext, brick_vox: int):
        self.gpu = gpu
        self.brick_voxels = brick_vox ** 3
        self.capacity = 0
        self.voxels: cl.Buffer | None = None
        self.field: cl.Buffer | None = None
        self.free: list[int] = []  # slots not holding a brick, taken from the end

    @property
    def stored(self) -> int:
        return self.capacity - len(self.free)

    @property
    def device_bytes(self) -> int:
        return self.capacity * self.brick_voxels * BYTES_PER_STORED_VOXEL

    def _sizes(self, capacity: int) -> list[int]:
        return [capacity * self.brick_voxels, 2 * capacity * self.brick_voxels]

    def reserve(self, bricks: int) -> None:
        """Make room for ``bricks`` more stored bricks, growing the pools if need be; raises
        DeviceMemoryExceeded, with nothing changed, when they cannot fit in the budget."""
        needed = self.stored + bricks
        if needed <= self.capacity:
            return
        # Half again as many, or as many as fit (the old pair stays allocated while the stored
        # bricks are copied, and the field buffer is the larger): never just what is needed, or
        # a full pool would be copied again at every edit.
        free = self.gpu.memory_budget_bytes - self.gpu.allocated_bytes
        fitting = min(free // (BYTES_PER_STORED_VOXEL * self.brick_voxels),
                      self.gpu.max_allocation_bytes // (2 * self.brick_voxels))
        wanted = min(max(needed, self.capacity + self.capacity // 2, FIRST_CAPACITY_BRICKS), fitting)
        if wanted < needed:
            self.gpu.check_fits(self._sizes(needed), f"{bricks} more stored bricks")  # says why
            raise DeviceMemoryExceeded(f"{bricks} more stored bricks do not fit")
        self._grow(wanted)

    def check_room(self, bricks: int) -> None:
        """Raise DeviceMemoryExceeded unless pools of ``bricks`` more could be allocated now."""
        self.gpu.check_fits(self._sizes(self.stored + bricks), f"{bricks} stored bricks")

    def _grow(self, capacity: int) -> None:
        sizes = self._sizes(capacity)
        voxels = self.gpu.allocate(sizes[0])
        try:
            field = self.gpu.allocate(sizes[1])
        except BaseException:
            self.gpu.release(voxels, sizes[0])
            raise
        old = self._sizes(self.capacity)
        if self.capacity:
            count = self.capacity * self.brick_voxels
            bulk.copy(self.gpu, voxels, self.voxels, np.uint8, count)
            bulk.copy(self.gpu, field, self.field, np.uint16, count)
            self.gpu.queue.finish()  # the copies read the old pair
            self.gpu.release(self.voxels, old[0])
            self.gpu.release(self.field, old[1])
        # Lowest slots last, taken first: stored bricks stay packed at the start of the pools.
        self.free[:0] = range(capacity - 1, self.capacity - 1, -1)
        self.voxels, self.field, self.capacity = voxels, field, capacity

    def take(self, count: int) -> np.ndarray:
        if count > len(self.free):
            raise RuntimeError(f"{count} slots taken with {len(self.free)} free: a batch was not reserved")
        taken = self.free[len(self.free) - count:]
        del self.free[len(self.free) - count:]
        return np.asarray(taken[::-1], dtype=np.int32)

    def give(self, slots: np.ndarray) -> None:
        self.free.extend(slots[::-1].tolist())

    def release(self) -> None:
        if self.capacity:
            self.gpu.queue.finish()
            sizes = self._sizes(self.capacity)
            self.gpu.release(self.voxels, sizes[0])
            self.gpu.release(self.field, sizes[1])
        self.voxels = self.field = None
        self.capacity, self.free = 0, []

    def shrink(self, headroom: float = SHRINK_HEADROOM) -> bool:
        """Give back the unused end of the pools when every stored brick sits before it (after a
        generator filled them in order), keeping ``headroom`` of the stored bricks free for the
        edits to come: the pools are copied to a smaller pair. Returns whether they shrank (not
        when the copy would not fit beside them)."""
        stored = self.stored
        capacity = max(FIRST_CAPACITY_BRICKS, stored + int(stored * headroom))
        if capacity >= self.capacity or sorted(self.free) != list(range(stored, self.capacity)):
            return False
        try:
            self.gpu.check_fits(self._sizes(capacity), "the shrunk brick pools")
        except DeviceMemoryExceeded:
            return False
        old_capacity, old_free = self.capacity, self.free
        self.free = list(range(capacity - 1, stored - 1, -1))
        self.capacity = capacity
        sizes = self._sizes(capacity)
        voxels = self.gpu.allocate(sizes[0])
        field = self.gpu.allocate(sizes[1])
        count = stored * self.brick_voxels
        bulk.copy(self.gpu, voxels, self.voxels, np.uint8, count)
        bulk.copy(self.gpu, field, self.field, np.uint16, count)
        self.gpu.queue.finish()
        old = self._sizes(old_capacity)
        self.gpu.release(self.voxels, old[0])
        self.gpu.release(self.field, old[1])
        self.voxels, self.field = voxels, field
        del old_free
        return True
