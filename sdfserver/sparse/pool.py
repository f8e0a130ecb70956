"""A sparse world's brick pools on the device: stored bricks' voxels (uchar) and packed field
(ushort), 3 bytes a stored voxel, and the free slots.

The pools are up to ``MAX_SEGMENTS`` segments, each a pair of buffers of at most
``segment_bricks`` bricks (what the device's largest buffer holds of field: a quarter of the
memory on NVIDIA's OpenCL), so the pools together may use the whole budget; slot ``s`` is brick
``s % segment_bricks`` of segment ``s // segment_bricks`` (kernels/bricks.cl and
kernels/include/field_source.h take every segment's buffers). Only the last segment grows: a pair
half again as large (or as large as fits) is allocated, its bricks copied over, the old pair
released — a copy of at most one segment, and growing by a fraction keeps it to a constant per
brick over time; a full last segment is followed by a new one, copying nothing. Every allocation
is checked against the budget first (DeviceMemoryExceeded, nothing changed). Slots are reserved
before a batch is accepted (``reserve``), so a recompute never runs out halfway."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from sdfserver import bulk
from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.gpu import GpuContext

BYTES_PER_STORED_VOXEL = 3  # voxel uchar + field ushort
FIRST_CAPACITY_BRICKS = 64
MAX_SEGMENTS = 4  # the kernels' pool arguments of each kind
# What a shrink keeps free, of the stored bricks: edits after a generator rarely grow the pools
# (a growth copies a segment), at 0.375 bytes a stored voxel.
SHRINK_HEADROOM = 0.125


@dataclass
class Segment:
    voxels: cl.Buffer
    field: cl.Buffer
    capacity: int  # bricks


class BrickPool:
    def __init__(self, gpu: GpuContext, brick_vox: int, segment_bricks: int | None = None):
        self.gpu = gpu
        self.brick_voxels = brick_vox ** 3
        self.segment_bricks = segment_bricks or max(1, gpu.max_allocation_bytes // (2 * self.brick_voxels))
        self.segments: list[Segment] = []
        self.free: list[int] = []  # slots not holding a brick, taken from the end

    @property
    def capacity(self) -> int:
        return sum(s.capacity for s in self.segments)

    @property
    def stored(self) -> int:
        return self.capacity - len(self.free)

    @property
    def device_bytes(self) -> int:
        return self.capacity * self.brick_voxels * BYTES_PER_STORED_VOXEL

    def _sizes(self, capacity: int) -> list[int]:
        return [capacity * self.brick_voxels, 2 * capacity * self.brick_voxels]

    def kernel_buffers(self, kind: str) -> tuple[cl.Buffer, ...]:
        """Every segment's ``voxels`` or ``field`` buffer, MAX_SEGMENTS of them (the first
        repeated where there is none: never read, as no slot names it); () with no segment."""
        buffers = [getattr(s, kind) for s in self.segments]
        return tuple(buffers + buffers[:1] * (MAX_SEGMENTS - len(buffers))) if buffers else ()

    # -- growth -------------------------------------------------------------------------------

    def _plan(self, needed: int) -> list[int]:
        """The segments' capacities after making room for ``needed`` bricks in all (raises
        DeviceMemoryExceeded when the budget or MAX_SEGMENTS cannot hold them)."""
        caps = [s.capacity for s in self.segments]
        free = self.gpu.memory_budget_bytes - self.gpu.allocated_bytes
        per_brick = BYTES_PER_STORED_VOXEL * self.brick_voxels
        while sum(caps) < needed:  # one loop over segments
            short = needed - sum(caps)
            if caps and caps[-1] < self.segment_bricks:  # the last one grows; its old pair stays while copied
                room = self.segment_bricks - caps[-1]
                grow = min(max(short, caps[-1] // 2), room, max(0, free // per_brick - caps[-1]))
                grow = max(grow, min(short, room))
                if (caps[-1] + grow) * per_brick > free:
                    raise self._exceeded(needed, free)
                free -= grow * per_brick
                caps[-1] += grow
            elif len(caps) < MAX_SEGMENTS:
                wanted = min(self.segment_bricks, max(short, FIRST_CAPACITY_BRICKS, caps[-1] // 2 if caps else 0))
                wanted = max(min(wanted, free // per_brick), min(short, self.segment_bricks))
                if wanted * per_brick > free:
                    raise self._exceeded(needed, free)
                free -= wanted * per_brick
                caps.append(wanted)
            else:
                raise DeviceMemoryExceeded(f"{needed} stored bricks need more than {MAX_SEGMENTS} pool segments "
                                           f"of {self.segment_bricks} bricks")
        return caps

    def _exceeded(self, needed: int, free: int) -> DeviceMemoryExceeded:
        more = needed - self.stored
        return DeviceMemoryExceeded(
            f"{more} more stored bricks need {more * BYTES_PER_STORED_VOXEL * self.brick_voxels / 2**20:.0f} MiB "
            f"of device memory (a growing segment's old pair held while it is copied); "
            f"{(self.gpu.memory_budget_bytes - self.gpu.allocated_bytes) / 2**20:.0f} MiB of the "
            f"{self.gpu.memory_budget_bytes / 2**20:.0f} MiB budget is free")

    def check_room(self, bricks: int) -> None:
        """Raise DeviceMemoryExceeded unless ``bricks`` more could be stored now."""
        self._plan(self.stored + bricks)

    def reserve(self, bricks: int) -> None:
        """Make room for ``bricks`` more stored bricks, growing the pools if need be; raises
        DeviceMemoryExceeded, with nothing changed, when they cannot fit in the budget."""
        caps = self._plan(self.stored + bricks)
        for k, capacity in enumerate(caps):  # one loop over segments
            if k >= len(self.segments):
                self._add_segment(capacity)
            elif capacity != self.segments[k].capacity:
                self._resize_segment(k, capacity)

    def _allocate(self, capacity: int) -> tuple[cl.Buffer, cl.Buffer]:
        sizes = self._sizes(capacity)
        voxels = self.gpu.allocate(sizes[0])
        try:
            return voxels, self.gpu.allocate(sizes[1])
        except BaseException:
            self.gpu.release(voxels, sizes[0])
            raise

    def _add_segment(self, capacity: int) -> None:
        first = len(self.segments) * self.segment_bricks
        self.segments.append(Segment(*self._allocate(capacity), capacity))
        self.free[:0] = range(first + capacity - 1, first - 1, -1)  # lowest last: taken first

    def _resize_segment(self, k: int, capacity: int) -> None:
        """Copy segment ``k`` into a pair of ``capacity`` bricks; growing adds its new slots,
        shrinking needs its slots past ``capacity`` free (the caller checks)."""
        old = self.segments[k]
        voxels, field = self._allocate(capacity)
        count = min(capacity, old.capacity) * self.brick_voxels
        bulk.copy(self.gpu, voxels, old.voxels, np.uint8, count)
        bulk.copy(self.gpu, field, old.field, np.uint16, count)
        self.gpu.queue.finish()  # the copies read the old pair
        self._release_segment(old)
        first = k * self.segment_bricks
        if capacity > old.capacity:
            self.free[:0] = range(first + capacity - 1, first + old.capacity - 1, -1)
        else:
            gone = set(range(first + capacity, first + old.capacity))
            self.free = [s for s in self.free if s not in gone]
        self.segments[k] = Segment(voxels, field, capacity)

    def _release_segment(self, segment: Segment) -> None:
        sizes = self._sizes(segment.capacity)
        self.gpu.release(segment.voxels, sizes[0])
        self.gpu.release(segment.field, sizes[1])

    def shrink(self, headroom: float = SHRINK_HEADROOM) -> bool:
        """Give back the unused end of the pools when every stored brick sits before it (after a
        generator filled them in order), keeping ``headroom`` of the stored bricks free for the
        edits to come: empty last segments go, the last one left is copied to a smaller pair.
        Returns whether they shrank (not when the copy would not fit beside them)."""
        stored, capacity = self.stored, self.capacity
        slots = sorted(self.free)
        tail = [k * self.segment_bricks + i for k, s in enumerate(self.segments) for i in range(s.capacity)][stored:]
        if slots != tail:
            return False
        keep = max(FIRST_CAPACITY_BRICKS, stored + int(stored * headroom))
        if keep >= capacity:
            return False
        while self.segments and capacity - self.segments[-1].capacity >= keep:  # one loop over segments
            last = self.segments.pop()
            capacity -= last.capacity
            self.gpu.queue.finish()
            self._release_segment(last)
            first = len(self.segments) * self.segment_bricks
            self.free = [s for s in self.free if s < first]
        if not self.segments or capacity == keep:
            return True
        k, new_capacity = len(self.segments) - 1, self.segments[-1].capacity - (capacity - keep)
        try:
            self.gpu.check_fits(self._sizes(new_capacity), "the shrunk brick pools")
        except DeviceMemoryExceeded:
            return True
        self._resize_segment(k, new_capacity)
        return True

    # -- slots ----------------------------------------------------------------------------------

    def take(self, count: int) -> np.ndarray:
        if count > len(self.free):
            raise RuntimeError(f"{count} slots taken with {len(self.free)} free: a batch was not reserved")
        taken = self.free[len(self.free) - count:]
        del self.free[len(self.free) - count:]
        return np.asarray(taken[::-1], dtype=np.int32)

    def give(self, slots: np.ndarray) -> None:
        self.free.extend(slots[::-1].tolist())

    def release(self) -> None:
        if self.segments:
            self.gpu.queue.finish()
        for segment in self.segments:
            self._release_segment(segment)
        self.segments, self.free = [], []
