"""One launch for small boxes: fim, jfa and jfa_fim whole in local memory (kernels/one_launch.cl).

Computes: what fim (Algorithms 4 and 5), jfa (Algorithm 6) and jfa_fim (§4.5) compute, with
the same initial distances, passes and write-back, in one launch: one work-group holds a box in
local memory and runs every pass there. A box is the job's whole work box, or with padded
borders each chunk of the region (one work-group a chunk, the dissertation's chunked set-up,
§4.2.1). FIM decides convergence inside the work-group, so a run costs no host round trip per
pass; its count of passes comes back after the launch, read only when someone asks for it.
Source: Fedor 2025 §4.3–4.5; the kernel reuses region.cl's initial distances and packing.
Results: fim and jfa_fim reach the same least fixed point (the exact field), so they equal the
multi-launch field voxel for voxel. Jump flooding keeps jfa.cl's passes, candidate order and
strict ties, so it finds the same nearest seeds and the same (approximate) field. FIM's pass
count is its own: it relaxes in place along z-segments, so the count can differ.
Units: voxels. Halo: the job's (seed shell, ``cap`` voxels, or none with padding).
Limits: a box fits when its distances (1 byte a voxel; with jump flooding 4 more for two packed
seed buffers, each seed ``ceil(log2(side))`` bits an axis, 16 at most) fit the device's local
memory beside the kernel's own, checked at run time; otherwise the algorithms run as before, a
launch a pass. A box is also at most ``MAX_BOX_VOXELS``: one work-group runs on one compute unit,
so a single large box would leave the rest of the device idle, and it could not be cut into
pieces (``base.Pieces``); padded regions of any size are cut between their chunks' groups.
On an NVIDIA GPU (``takes_crews``) a lone box past ``LONE_GROUP_VOXELS`` is taken by a crew
(kernels/include/crew.h): the groups of one launch that run together, each holding the whole box
and running its share of every pass, with barriers between them through global memory, so a
pass is spread over several compute units and still costs no launch. Its groups all fit the
device at once (at most one a compute unit), and a group that starts after the others have begun
takes no part.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from sdfserver import bulk
from sdfserver.algorithms.base import (
    AlgorithmRun, Pieces, RegionJob, SlabPace, int4, pack_region, seeds_weigh_nothing, slabs,
)
from sdfserver.gpu import GpuContext

MAX_ITEMS = 1024  # work-items a group: a GPU's usual maximum, and enough for a 32^2 column layer
# The largest box one work-group takes, whatever local memory allows: a larger one would keep one
# compute unit busy for long, which neither beats a launch a pass nor can be cut into pieces.
MAX_BOX_VOXELS = 32 ** 3
# A packed seed's bits. All ones is SEED_NONE: with 16 bits in all, some side is not a power of two
# (a box of powers of two has at most MAX_BOX_VOXELS = 2^15 voxels: 15 bits), so no seed is all ones.
SEED_BITS = 16
# A flood pass ranks a candidate by a 32-bit key: its cost in the top COST_BITS (kernels/one_launch.cl's
# COST_SHIFT), its place in jfa.cl's order and its seed below. A box whose costs could pass them floods
# a launch a pass.
COST_BITS = 11
# The largest box a lone work-group (one box, not padded chunks) takes, by whether it floods.
LONE_GROUP_VOXELS = {False: 16 ** 3, True: 1024}
# A crew's groups: one for each CREW_VOXELS_PER_GROUP voxels of the box (by whether it floods), at
# most one a compute unit; a crew's flood takes chains of CREW_FLOOD_CHAIN voxels (FLOOD_CHAIN).
CREW_VOXELS_PER_GROUP = {False: 512, True: 512}
CREW_FLOOD_CHAIN = 2
CREW_INTS = 33  # kernels/include/crew.h's control block


@dataclass(frozen=True)
class Plan:
    """How one job runs in one launch."""

    box_n: tuple[int, int, int]  # a work-group's box: the work box, or the chunk when padded
    groups: int
    items: int  # work-items a group
    dist_bytes: int
    seed_bytes: int  # each of the two seed buffers (a placeholder without jump flooding)
    crew: bool = False  # the groups share one box (kernels/include/crew.h)


class _DeviceState:
    """What one context keeps for the path: each kernel variant's limits, and the int the FIM
    passes are counted in by runs that are enqueued whole (one is enough: the queue is in order,
    and each count is copied out before another run's launch writes it)."""

    def __init__(self, gpu: GpuContext):
        self.limits: dict[tuple[bool, bool, bool, bool], tuple[int, int]] = {}
        self.count = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE, size=4)
        # A crew's exchange (two halves of seeds, the distances) and its control block, which
        # every launch leaves zeroed; one set serves every run, the queue being in order.
        half = _round_up(MAX_BOX_VOXELS, 8)
        self.crew_seeds = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE, size=2 * 2 * half)
        self.crew_dist = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE, size=_round_up(MAX_BOX_VOXELS, 16))
        self.crew = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR,
                              hostbuf=np.zeros(CREW_INTS, np.int32))


_STATES: "weakref.WeakKeyDictionary[GpuContext, _DeviceState]" = weakref.WeakKeyDictionary()


def _state(gpu: GpuContext) -> _DeviceState:
    state = _STATES.get(gpu)
    if state is None:
        state = _STATES[gpu] = _DeviceState(gpu)
    return state


def _bits(side: int) -> int:
    return (side - 1).bit_length()


def _round_up(n: int, multiple: int) -> int:
    return -(-n // multiple) * multiple


def takes_crews(gpu: GpuContext) -> bool:
    """Whether lone boxes take crews on this device: a GPU runs a small launch's groups together,
    where a CPU device may run them one after another (a crew survives that, shrinking to one
    group, but cannot gain from it); and only on NVIDIA's can the kernel order memory across the
    device as a crew's barrier needs (PTX's GPU-scope acquire and release, kernels/include/crew.h)."""
    return bool(gpu.device.type & cl.device_type.GPU) and bool(gpu.programs.device_defines.get("SDF_NVIDIA"))


def crew_groups(gpu: GpuContext, voxels: int, flood: bool) -> int:
    """The groups launched for a crew of a box of ``voxels``: one a compute unit at most, so that
    all of them can run at once."""
    return max(1, min(voxels // CREW_VOXELS_PER_GROUP[flood], gpu.device.max_compute_units))


class OneLaunch:
    """The one-launch form of one algorithm: ``flood`` (jump flooding first) and ``relax`` (FIM
    passes to convergence, last)."""

    def __init__(self, flood: bool, relax: bool):
        self.flood, self.relax = flood, relax
        self.defines = {"ONE_LAUNCH_FLOOD": int(flood), "ONE_LAUNCH_RELAX": int(relax)}

    def weighted(self, job: RegionJob) -> bool:
        """Whether the flood reads seeds' weights (a kernel variant: without them a pass does less)."""
        return self.flood and not seeds_weigh_nothing(job)

    def kernel(self, gpu: GpuContext, weighted: bool = True, crew: bool = False) -> cl.Kernel:
        chain = {"FLOOD_CHAIN": CREW_FLOOD_CHAIN} if crew and self.flood else {}
        return gpu.programs.kernel("one_launch.cl", "one_launch", **{**chain, **self.defines},
                                   ONE_LAUNCH_WEIGHTED=int(weighted), ONE_LAUNCH_CREW=int(crew))

    def _limits(self, gpu: GpuContext, weighted: bool = True, crew: bool = False) -> tuple[int, int]:
        """(the most work-items a group, the local bytes left for the boxes)."""
        state = _state(gpu)
        key = (self.flood, self.relax, weighted, crew)
        found = state.limits.get(key)
        if found is None:
            kernel, device = self.kernel(gpu, weighted, crew), gpu.device
            items = min(MAX_ITEMS, device.max_work_group_size,
                        kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, device))
            static = kernel.get_work_group_info(cl.kernel_work_group_info.LOCAL_MEM_SIZE, device)
            found = state.limits[key] = (int(items), int(device.local_mem_size) - int(static))
        return found

    def chosen(self, gpu: GpuContext, job: RegionJob) -> Plan | None:
        """``plan``, where one launch is also the faster way: a lone work-group runs on one compute
        unit, so past ``LONE_GROUP_VOXELS`` a launch a pass over the whole device wins
        (docs/benchmarks.md, "Every algorithm"); many chunks in one launch fill the device."""
        plan = self.plan(gpu, job)
        if plan is None or plan.groups > 1:
            return plan
        voxels = math.prod(plan.box_n)
        if voxels <= LONE_GROUP_VOXELS[self.flood]:
            return plan
        return self.plan(gpu, job, crew=True) if takes_crews(gpu) else None

    def plan(self, gpu: GpuContext, job: RegionJob, crew: bool = False) -> Plan | None:
        """How ``job`` runs in one launch, or None where a box does not fit the device. ``crew``:
        a lone box in a crew of groups (none for padded chunks, which have a group each)."""
        if crew and job.chunk:
            return None
        if job.invert or job.signed:
            return None
        if job.chunk:
            box_n = (job.chunk,) * 3
            groups = math.prod(w // job.chunk for w in job.work_box.shape_xyz)
        else:
            box_n, groups = job.work_box.shape_xyz, 1
        voxels = math.prod(box_n)
        if not 0 < voxels <= MAX_BOX_VOXELS:
            return None
        seed_bytes = _round_up(2 * voxels, 16) if self.flood else 4
        if self.flood and (sum(_bits(n) for n in box_n) > SEED_BITS
                           or job.cap + sum(n - 1 for n in box_n) >= 1 << COST_BITS):
            return None
        items_max, local_bytes = self._limits(gpu, self.weighted(job), crew)
        dist_bytes = _round_up(voxels, 16)
        if dist_bytes + 2 * seed_bytes > local_bytes:
            return None
        columns = box_n[0] * box_n[1]
        items = columns * min(box_n[2], items_max // columns) if columns <= items_max else items_max
        if crew:
            groups = crew_groups(gpu, voxels, self.flood)
        return Plan(box_n, groups, items, dist_bytes, seed_bytes, crew)

    def pieces(self, gpu: GpuContext, job: RegionJob, run: AlgorithmRun, plan: Plan, piece_s: float | None,
               first_step: int = 0, extra_passes: int = 0) -> Pieces:
        """The job in one launch; with ``piece_s`` and several groups (padded chunks), launches of
        a run of groups each, paced like ``slabs``, writing scratch until pack_region at the end."""
        b, state = job.buffers, _state(gpu)
        kernel = self.kernel(gpu, self.weighted(job), plan.crew)
        cut = piece_s is not None and plan.groups > 1 and not plan.crew
        accumulate = plan.groups > 1 and not plan.crew
        # A run in pieces counts in an int of its own: other runs are enqueued between its pieces.
        count = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE, size=4) if cut and self.relax else state.count
        if self.relax and accumulate:
            run.events.append(bulk.fill(gpu, count, np.int32, 0, 1))
        fixed = (b.voxels, b.field, b.work, int4(b.dims), int4(job.work_box.lo), int4(job.work_box.shape_xyz),
                 int4(job.region.lo), int4(job.region.hi), int4(plan.box_n), np.int32(job.seeded),
                 np.int32(job.cap), np.int32(job.chunk))
        tail = (np.int32(first_step), np.int32(extra_passes), count, np.int32(accumulate),
                cl.LocalMemory(plan.dist_bytes), cl.LocalMemory(plan.seed_bytes), cl.LocalMemory(plan.seed_bytes),
                state.crew_seeds, state.crew_dist, state.crew)

        own = b.kernels  # a dense world's copy sets only the arguments that changed since its last launch

        def launch(first_group: int, groups: int) -> cl.Event:
            args = (*fixed, np.int32(first_group), np.int32(cut), *tail)
            if own is not None:
                return own.enqueue(gpu.queue, kernel, (groups * plan.items,), (plan.items,), args)
            return kernel(gpu.queue, (groups * plan.items,), (plan.items,), *args)

        if cut:
            yield from slabs(run, launch, plan.groups, SlabPace(piece_s, 1))
            run.events.append(pack_region(gpu, job, b.work))
        else:
            run.events.append(launch(0, plan.groups))
        if self.relax:
            run.count_later(gpu, count)
