"""exact — the default: separable exact Manhattan distance transform.

Computes: the exact L1 distance to the nearest solid voxel, capped, over R.
Source: the L1 transform is separable (Meijster, Roerdink & Hesselink 2000;
Felzenszwalb & Huttenlocher 2012): three 1-D min-plus passes along x, y and z,
each a forward and a backward sweep; O(1) work per voxel per pass, every line
in parallel. Not in the dissertation; it replaces its per-chunk algorithms.
Kernel: kernels/exact.cl, three launches; the first derives initial distances
from voxels and the seed shell, the last writes the packed field.
Units: voxels. Halo: one-voxel seed shell (seeded) or ``cap`` voxels (halo).
Signed worlds: a second run with ``RegionJob.invert`` writes each solid's distance to the
nearest air voxel over R's solids (kernels/exact.cl, INVERT).
Exact: yes, across chunk borders. Failure modes: none known; lines are at
most 2048 voxels (the world size limit), 128 segments of 16 at the longest.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from functools import partial
from typing import Callable

import numpy as np

from sdfserver.algorithms.base import WORK_PLANE_PAD, AlgorithmRun, RegionJob, int4
from sdfserver.gpu import GpuContext
from sdfserver.gpu.slots import SlotPool

MAX_GROUP = 1024  # work-items per work-group
NO_STRIDE = np.int64(0)  # a run of one world: no slots (kernels/exact.cl, SLOT_PROLOGUE)
SLOT_MASK_BITS = 256  # the passes' slot mask, an int8 (gpu/slots.py's POOL_MAX_SLOTS at most)
NO_SLOTS = bytes(SLOT_MASK_BITS // 8)
RUNS_KEPT_PER_POOL = 64  # stacked runs' arguments kept per pool (subsets of its slots, caps)


@dataclass(frozen=True)
class PassShape:
    """How one pass cuts its lines: measured with tools/tune_exact.py (docs/benchmarks.md). With
    the carries scanned in log2(segments) steps, 32 segments of 16 won in every pass; the y pass sweeps 8 x-columns per work-item, the z pass
    (rows a whole slice apart) 4. Four x-lanes a work-group won everywhere but in the z pass of
    lines of 1024 and more, where eight do (a warp then reads whole 32-byte sectors of a row)."""

    segments: int  # work-items per line a segment length is chosen for (segment_length)
    min_seg: int
    max_seg: int  # elements per work-item (registers)
    vec: int = 1  # x-columns per work-item (y and z passes)
    lanes: int = 1  # work-items across x per work-group (y and z passes)
    long_lanes: int = 0  # lanes for lines of at least long_line voxels (0: lanes)
    long_line: int = 1024

    def lanes_for(self, line_len: int) -> int:
        return self.long_lanes if self.long_lanes and line_len >= self.long_line else self.lanes


PASS_SHAPES = {
    0: PassShape(segments=32, min_seg=8, max_seg=16),
    1: PassShape(segments=32, min_seg=4, max_seg=16, vec=8, lanes=4),
    2: PassShape(segments=32, min_seg=4, max_seg=16, vec=4, lanes=4, long_lanes=8),
}
# The first pass derives initial distances from voxels and the seed shell, the last packs the
# field; the order is free (the transform is separable). Measured on the H200 at 512^3.
PASS_ORDER = (0, 1, 2)
X_PASS_THREADS = 128  # work-items per work-group for the x pass (tuned on the H200)
COUNT_STEP = 8  # a line's segment count is a multiple of this (segment_count)
PASSES_MEMO_SIZE = 1024  # work-box shapes remembered per device; region shapes repeat


def segment_length(line_len: int, shape: PassShape, lanes: int | None = None) -> int:
    """A power of two near line_len / segments, within the shape's bounds and the group limit."""
    seg = shape.min_seg
    while seg < shape.max_seg and seg * shape.segments < line_len:
        seg *= 2
    while -(-line_len // seg) * max(1, lanes or shape.lanes_for(line_len)) > MAX_GROUP:
        seg *= 2
    return seg


def segment_count(line_len: int, seg: int, shape: PassShape) -> int:
    """Work-items per line: just enough segments of ``seg`` to cover it, rounded up to
    COUNT_STEP, so that few sit idle (they only pad the scans and hold an SM's slots) while the
    compiled variants stay few whatever region sizes incremental updates bring."""
    return -(-line_len // (seg * COUNT_STEP)) * COUNT_STEP


def pass_variant(axis: int, line_len: int, seg: int | None = None, lanes: int | None = None) -> tuple[int, int, int]:
    """What a pass's program depends on for a line of line_len: (segment length, segments, lanes),
    the tuned shape's unless ``seg`` or ``lanes`` override it."""
    shape = PASS_SHAPES[axis]
    lanes = lanes or shape.lanes_for(line_len)
    seg = seg or segment_length(line_len, shape, lanes)
    return seg, segment_count(line_len, seg, shape), lanes


def work_plane(job: RegionJob) -> int:
    """Bytes between z-planes of the work box: a plane and WORK_PLANE_PAD (World allocates it)."""
    nx, ny, _ = job.work_box.shape_xyz
    return nx * ny + WORK_PLANE_PAD


def bytes_moved(job: RegionJob) -> int:
    """The bytes the three passes must move, for achieved bandwidth: over the work box W the
    first reads voxels and writes work, the second reads and writes work, the last reads work;
    the last writes the 2-byte field over R. The seed shell's field reads and the last pass's
    colour reads (only where solids are) are not counted."""
    return 5 * job.work_box.volume + 2 * job.region.volume


class Exact:
    name = "exact"
    exact = True
    # Work boxes on multiples of 16 voxels along x: a work-group of the last pass (4 x-lanes of 4
    # columns) then writes whole 32-byte sectors of the field's rows, not halves of two
    # (docs/benchmarks.md, "Incremental edits").
    x_align = 16

    def __init__(self) -> None:
        # Per program cache (one per device context), gone with it.
        self._passes: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    def launch_shape(self, gpu: GpuContext, axis: int, line_len: int, nx: int, ny: int, nz: int,
                     seg: int | None = None, lanes: int | None = None, vec: int | None = None,
                     x_threads: int = X_PASS_THREADS, first: bool = False, last: bool = False,
                     invert: bool = False, world_out: bool = False, signed_world: bool = False):
        """The kernel, segments per line, and global/local sizes for one pass.

        Each pass is compiled for its work-group shape (reqd_work_group_size),
        so the compiler fits registers to it. seg, lanes and vec override the
        tuned shape (tools/tune_exact.py).
        """
        seg, nseg, lanes = pass_variant(axis, line_len, seg, lanes)
        if axis == 0:
            per_group = max(1, x_threads // nseg)  # line pairs: two lines share each word
            local = (nseg, per_group)
            pairs = -(-(ny * nz) // 2)
            global_ = (nseg, -(-pairs // per_group) * per_group)
            kernel = gpu.programs.kernel("exact.cl", "pass_x", SEG=seg, LOCAL_X=local[0], LOCAL_Y=local[1],
                                         FIRST=int(first), LAST=int(last), **({"INVERT": 1} if invert else {}),
                                         **({"WORLD_OUT": 1} if world_out else {}),
                                         **({"SIGNED_WORLD": 1} if signed_world else {}))
        else:
            vec = vec or PASS_SHAPES[axis].vec
            local = (lanes, nseg)
            columns = -(-nx // vec)
            global_ = (-(-columns // lanes) * lanes, nseg * (nz if axis == 1 else ny))
            kernel = gpu.programs.kernel("exact.cl", "pass_yz", SEG=seg, AXIS=axis, VEC=vec,
                                         LOCAL_X=local[0], LOCAL_Y=local[1],
                                         FIRST=int(first), LAST=int(last), **({"INVERT": 1} if invert else {}),
                                         **({"SIGNED_WORLD": 1} if signed_world else {}))
        return kernel, nseg, global_, local

    @staticmethod
    def enqueue(gpu: GpuContext, job: RegionJob, kernel, global_, local):
        """Launch one pass over the job's work box; returns its event."""
        return kernel(gpu.queue, global_, local, *pass_args(job))

    def prebuild(self, gpu: GpuContext, max_line: int = 2048) -> int:
        """Build every pass variant a line of up to max_line voxels can need; returns how many.

        A pass's program follows from its line's segment length, count and lanes
        (``pass_variant``), which every region shape's lines of 8, 16, ... max_line voxels
        (work boxes are multiples of 8 along x, chunks along y and z) cover.
        """
        programs, built = set(), set()
        for line in range(8, max_line + 1, 8):
            for position, axis in enumerate(PASS_ORDER):
                variant = (axis, *pass_variant(axis, line))  # the y and z passes may share a shape
                if variant not in built:
                    built.add(variant)
                    kernel, *_ = self.launch_shape(gpu, axis, line, line, line, line,
                                                   first=position == 0, last=position == 2)
                    programs.add(kernel.program.int_ptr)
        return len(programs)

    def passes(self, gpu: GpuContext, n: tuple[int, int, int], invert: bool = False,
               signed_world: bool = False) -> list:
        """The three passes' (kernel, segments, global, local) for a work box of shape ``n``,
        memoized per device: working them out costs more host time than launching them.
        ``invert``: a signed world's distances inside solids (kernels/exact.cl, INVERT);
        ``signed_world``: either run of a signed world (SIGNED_WORLD)."""
        memo = self._passes.setdefault(gpu.programs, {})
        found = memo.get((n, invert, signed_world))
        if found is None:
            if len(memo) >= PASSES_MEMO_SIZE:
                memo.clear()
            found = memo[n, invert, signed_world] = [
                self.launch_shape(gpu, axis, n[axis], *n, first=position == 0, last=position == 2, invert=invert,
                                  signed_world=signed_world)
                for position, axis in enumerate(PASS_ORDER)]
        return found

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        run = AlgorithmRun(bytes_moved=bytes_moved(job))
        args = pass_args(job)  # the three passes take the same arguments
        queue, own = gpu.queue, job.buffers.kernels
        for kernel, _, global_, local in self.passes(gpu, job.work_box.shape_xyz, job.invert, job.signed):
            if own is None:
                run.events.append(kernel(queue, global_, local, *args))
            else:  # the world's copy: only the arguments that changed since its last launch are set
                run.events.append(own.enqueue(queue, kernel, global_, local, args))
        return run

    def run_slots(self, gpu: GpuContext, pool: SlotPool, slots: list[int], job: RegionJob) -> AlgorithmRun:
        """The whole-world transform of the worlds in ``slots`` of ``pool``, one launch a pass for all
        of them (kernels/exact.cl, SLOT_PROLOGUE). ``job``: the whole-world job of any one of them
        (unsigned, borders exact; one cap for all): the worlds share its shape, cap and arguments but
        for their buffers, which are the pool's. The arguments are kept per pool while the slots and
        the cap repeat, so the kernel copies set none."""
        if job.region != job.world_box or job.invert or job.signed or job.chunk:
            raise ValueError("a stacked run transforms whole unsigned worlds with exact borders")
        key = (tuple(slots), job.cap)
        args = pool.runs.get(key)
        if args is None:
            if len(pool.runs) >= RUNS_KEPT_PER_POOL:
                pool.runs.clear()
            voxel_stride, _, work_stride = pool.sizes
            args = list(pass_args(job))
            args[:3] = pool.work, pool.voxels, pool.field
            args[-3:] = slot_table(slots), np.int64(voxel_stride), np.int64(work_stride)
            args = pool.runs[key] = tuple(args)
        run = AlgorithmRun(bytes_moved=bytes_moved(job) * len(slots))
        for kernel, _, global_, local in self.passes(gpu, job.work_box.shape_xyz):
            run.events.append(pool.kernels.enqueue(gpu.queue, kernel, (*global_, len(slots)), (*local, 1), args))
        return run

    def prepare(self, gpu: GpuContext, job: RegionJob) -> Callable[[], AlgorithmRun]:
        """``run(gpu, job)`` worked out once, for a world that runs the same job step after step
        (``World`` keeps it while the dirty regions repeat): each call only enqueues the three
        passes, on the world's kernel copies, whose arguments are still set from the last call."""
        own = job.buffers.kernels
        if own is None:
            return partial(self.run, gpu, job)
        args, moved, queue = pass_args(job), bytes_moved(job), gpu.queue
        launches = [(kernel, global_, local) for kernel, _, global_, local in
                    self.passes(gpu, job.work_box.shape_xyz, job.invert, job.signed)]

        def run() -> AlgorithmRun:
            events = [own.enqueue(queue, kernel, global_, local, args) for kernel, global_, local in launches]
            return AlgorithmRun(events, bytes_moved=moved)

        return run


def slot_table(slots: list[int]) -> bytes:
    """The passes' ``int8 slots`` argument: the mask of the slots a stacked run's launch covers
    (kernels/exact.cl, kth_slot), which it runs in ascending order."""
    mask = np.zeros(SLOT_MASK_BITS // 32, dtype=np.uint32)
    for slot in slots:
        if not 0 <= slot < SLOT_MASK_BITS:
            raise ValueError(f"a stacked run covers slots 0 to {SLOT_MASK_BITS - 1}, got {slot}")
        mask[slot // 32] |= np.uint32(1 << (slot % 32))
    return mask.tobytes()


def pass_args(job: RegionJob) -> tuple:
    """The arguments of every pass over ``job`` (kernels/exact.cl)."""
    b, work_box = job.buffers, job.work_box
    world = job.world_box
    return (b.work, b.voxels, b.field, int4(b.dims), int4(work_box.lo), int4(work_box.shape_xyz),
            int4(job.region.lo), int4(job.region.hi),
            np.int32(job.seeded), np.int32(job.cap), np.int32(work_plane(job)), int4(world.lo), int4(world.hi),
            NO_SLOTS, NO_STRIDE, NO_STRIDE)
