"""Slot pools: small dense worlds of one size side by side in shared device buffers.

A world's recompute costs the engine thread a few kernel launches whatever the world's size,
and on NVIDIA's driver a launch costs the host about as much as a 128³ transform costs the
device. Worlds of one size kept in the slots of one pool (their voxels, field and ``work``
buffers are sub-buffers of the pool's) can be transformed together, one launch a pass for all
of them (``Exact.run_slots``), which is what lets many small worlds cost about what one does.

Only worlds of at most ``POOLED_MAX_VOXELS`` take a slot, and only where each of their buffers
is a whole number of the device's sub-buffer alignment (``MEM_BASE_ADDR_ALIGN``). A pool holds
as many worlds as fit ``POOL_BYTES``, from ``POOL_MIN_SLOTS`` to ``POOL_MAX_SLOTS`` (a stacked
run and a pooled brush launch cover one pool, so the fewer pools a step's worlds are in, the
fewer launches the step makes); a pool is made when a world finds no free slot, and released
when its last world goes. A pool is made only while it takes at most ``POOL_BUDGET_SHARE`` of the memory
budget still free, so that its empty slots never decide how many worlds fit; otherwise the world
allocates its own buffers, as larger worlds do. Used only on the engine thread (through
``World``), like every other allocation of the world table.

OpenCL leaves concurrent use of a buffer and its sub-buffers undefined. Every command that
touches a world's buffers or a pool's goes to the one in-order work queue (``download_later``'s
transfer queue reads only its private staging copy), so none runs beside another.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pyopencl as cl

from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.gpu.launches import KernelCopies

POOL_MIN_SLOTS = 8
POOL_MAX_SLOTS = 64  # kernels/exact.cl's slot mask has room for 256
POOL_BYTES = 512 << 20  # 64 worlds of 128³ (8 MiB each: voxels, field, work)
POOLED_MAX_VOXELS = 1 << 21  # 128³: past it a world's transform costs the device more than its launches cost the host
POOL_BUDGET_SHARE = 0.25


@dataclass
class SlotPool:
    dims: tuple[int, int, int]
    sizes: tuple[int, int, int]  # one slot's voxels, field and work bytes: the strides between slots
    voxels: cl.Buffer
    field: cl.Buffer
    work: cl.Buffer
    slots: int
    free: list[int]
    # The stacked runs' own kernel copies, and their arguments by (slots, cap) (Exact.run_slots):
    # they repeat from one step to the next.
    kernels: KernelCopies = field(default_factory=KernelCopies)
    runs: dict[tuple, tuple] = field(default_factory=dict)

    @property
    def used(self) -> int:
        return self.slots - len(self.free)


@dataclass
class Slot:
    """One world's place in a pool, and its sub-buffers (voxels, field, work)."""

    pool: SlotPool
    index: int
    buffers: tuple[cl.Buffer, cl.Buffer, cl.Buffer]


class SlotPools:
    def __init__(self, gpu) -> None:
        self.gpu = gpu
        self.pools: dict[tuple[int, int, int], list[SlotPool]] = {}
        self.align = max(1, gpu.device.mem_base_addr_align // 8)

    def poolable(self, dims: tuple[int, int, int], sizes: list[int]) -> bool:
        """Whether a world of ``dims`` whose voxels, field and work take ``sizes`` bytes may take a slot."""
        return dims[0] * dims[1] * dims[2] <= POOLED_MAX_VOXELS and all(s % self.align == 0 for s in sizes)

    @staticmethod
    def slots_per_pool(sizes: list[int]) -> int:
        """How many worlds whose voxels, field and work take ``sizes`` bytes a pool holds."""
        return max(POOL_MIN_SLOTS, min(POOL_MAX_SLOTS, POOL_BYTES // sum(sizes)))

    def take(self, dims: tuple[int, int, int], sizes: list[int]) -> Slot | None:
        """A free slot for a world of ``dims`` (``sizes``: its voxels, field and work bytes), a new
        pool made if none has one; None where the world may not take a slot or no pool fits."""
        if not self.poolable(dims, sizes):
            return None
        pools = self.pools.setdefault(dims, [])
        pool = next((p for p in pools if p.free), None)
        if pool is None:
            count = self.slots_per_pool(sizes)
            if sum(sizes) * count > POOL_BUDGET_SHARE * (self.gpu.memory_budget_bytes - self.gpu.allocated_bytes):
                return None
            try:
                parents = self.gpu.allocate_all([s * count for s in sizes])
            except DeviceMemoryExceeded:
                return None
            pool = SlotPool(dims, tuple(sizes), *parents, slots=count, free=list(range(count - 1, -1, -1)))
            pools.append(pool)
        index = pool.free.pop()
        subs = tuple(parent.get_sub_region(index * size, size)
                     for parent, size in zip((pool.voxels, pool.field, pool.work), sizes))
        return Slot(pool, index, subs)

    def give_back(self, slot: Slot) -> None:
        """Release ``slot``'s sub-buffers and free it; a pool left empty is released."""
        for sub in slot.buffers:
            sub.release()
        pool = slot.pool
        pool.free.append(slot.index)
        if not pool.used:
            self.pools[pool.dims].remove(pool)
            if not self.pools[pool.dims]:
                del self.pools[pool.dims]
            for parent, size in zip((pool.voxels, pool.field, pool.work), pool.sizes):
                self.gpu.release(parent, size * pool.slots)
