"""jfa, jfa+1, jfa+2 — Jump Flooding (Rong & Tan 2006; the dissertation's Algorithm 6, §4.4).

Computes: every voxel's nearest seed, found by passes with step sizes halving
from half the box's longest side (rounded up to a power of two; no larger than
the cap needs) down to 1. Each pass offers a voxel the nearest seeds of its 26
neighbours ``step`` away (all of {-step, 0, step}^3) and keeps the cheapest,
reading one buffer and writing the other (ping-pong). The distance is the
Manhattan distance to the seed found, plus the seed's weight, capped. Seeds
are solids (weight 0) and, in a seeded job, the seed shell (weight: its
distance in the current field). ``jfa+1`` adds a pass of step 1 at the end,
``jfa+2`` passes of step 2 and 1 (Rong & Tan's JFA+1 and JFA+2).
Source: Rong & Tan, "Jump flooding in GPU with applications to Voronoi diagram
and distance transform", I3D 2006; Fedor 2025 §4.4.
Kernel: kernels/jfa.cl (+ region.cl), one launch a pass: the first finds the
seeds in the initial distances, the last writes distances. Where every seed is
a solid (a whole world, a halo, padded chunks: ``seeds_weigh_nothing``) a
candidate's cost is its offset's length and no weight is read, and a work-item
takes a block of voxels a step apart (up to 2 x 2 x 2 groups of four along x),
whose shared rows of neighbours it reads once; otherwise the passes read the
winning seeds' weights, a voxel an item. Both find the same seeds, in the same
order, with the same ties. Scratch: two uint nearest-seed buffers (WorldBuffers.seeds/seeds2,
8 bytes per voxel), held only by worlds that flood.
A box that fits one work-group's local memory floods there in one launch, with
the same passes and ties (one_launch.py).
Units: voxels. Halo: seed shell or ``cap`` voxels; none with padded borders
(each chunk floods alone, its outside solid: §4.2.1).
Exact: no. Every candidate is the length of a real path, so the field is never
below the truth: jump flooding can only overestimate, where a voxel's nearest
seed did not reach it through the jumps. A ray that steps by such a field can
step past a solid (a sphere tracer is safe only with distances at or below the
truth). The error is measured by the tests and the benchmark, not assumed.
Cost: 26 neighbour seeds per voxel per pass (and, in a seeded job, the weights
of those that could win), log2(min(side, cap)) + extra passes. Each pass is
built with its step as a constant: a box's passes are a handful of programs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.base import (
    AlgorithmRun, Pieces, RegionJob, SlabPace, grid, init_work, int4, pack_region, run_whole, seeds_weigh_nothing,
    slabs,
)
from sdfserver.algorithms.one_launch import OneLaunch, Plan
from sdfserver.gpu import GpuContext

EXTRA_STEPS = {0: (), 1: (1,), 2: (2, 1)}  # Rong & Tan's JFA, JFA+1, JFA+2


def first_step(longest_side_vox: int) -> int:
    """Half the side rounded up to a power of two: steps then reach any offset in the box."""
    if longest_side_vox < 2:
        return 0
    return 1 << ((longest_side_vox - 1).bit_length() - 1)


def step_sizes(job: RegionJob, extra_passes: int = 0) -> list[int]:
    """N/2 .. 1, then the extra passes. N is the longest side a seed can be worth crossing:
    the box's (the chunk's, when padded), and no more than the cap, since only seeds worth
    less than the cap are kept."""
    reach = job.chunk or max(job.work_box.shape_xyz)
    step, steps = first_step(min(reach, job.cap)), []
    while step >= 1:
        steps.append(step)
        step //= 2
    return steps + list(EXTRA_STEPS[extra_passes])


@dataclass(frozen=True)
class PassLayout:
    """How a pass's work-items cover the box: ``group`` items a work-group (x, y, z); with
    ``vector`` groups of four voxels along x where the job allows it (weight 0, the x side and
    the chunk multiples of 4), and then ``block`` of them along x, y and z (1 or 2 each, a
    stride apart: jfa.cl), which read the rows of neighbours they share once and share the
    arithmetic on each seed read."""

    group: tuple[int, int, int] = (16, 4, 2)
    vector: bool = True
    block: tuple[int, int, int] = (2, 2, 2)
    # Blocks only where a pass without them has at least this many work-items: below it the
    # device is not full, and an item's longer run is the pass's time (a 32³ flood took 1.7x
    # as long in blocks).
    min_items: int = 0


def block_items(side: int, stride: int, per_item: int) -> int:
    """Work-items along an axis of ``side`` (voxels, or groups of four along x) with
    ``per_item`` (1 or 2) an item a ``stride`` apart: item j starts at j // stride * 2 *
    stride + j % stride (jfa.cl's BLOCK_FIRST)."""
    if per_item == 1:
        return side
    return side // (2 * stride) * stride + min(side % (2 * stride), stride)


def pass_block(layout: PassLayout, shape_xyz: tuple[int, int, int], step: int,
               chunk: int) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
    """The block of a pass of ``step`` and the work-items that cover the box with it: the
    layout's, but 1 along an axis where two a stride apart would not share a chunk or the box
    has no second, and along x below a step of 4 (two groups of four side by side share reads
    but no arithmetic, and took longer than one); none in a box of fewer than
    ``layout.min_items`` groups of four."""
    strides = (max(step, 4), step, step)  # x: a group of four, or the step when it is longer
    block, items = [], []
    large = shape_xyz[0] // 4 * shape_xyz[1] * shape_xyz[2] >= layout.min_items
    for axis, (want, side, stride) in enumerate(zip(layout.block, shape_xyz, strides)):
        fits = large and step > 0 and side > stride and (chunk == 0 or chunk % (2 * stride) == 0)
        block.append(want if fits and (axis > 0 or step >= 4) else 1)
    for axis, (side, stride) in enumerate(zip((shape_xyz[0] // 4, *shape_xyz[1:]), (strides[0] // 4, step, step))):
        items.append(block_items(side, stride, block[axis]))
    return tuple(block), tuple(items)


LAYOUT = PassLayout(min_items=1 << 18)  # about what an H100 or H200 holds at once


def pass_kernel(gpu: GpuContext, shape_xyz: tuple[int, int, int], step: int, chunk: int, layout: PassLayout,
                vector: bool, weighted: bool, wide: int, first: bool, last: bool) -> tuple[cl.Kernel, tuple, tuple]:
    """One pass's kernel, global and local sizes: with ``vector``, groups of four voxels along x
    in ``layout``'s blocks (weight 0 only), else a voxel an item."""
    if vector:
        block, items = pass_block(layout, shape_xyz, step, chunk)
        name, defines = "jfa_seed_pass4", dict(zip(("JFA_BX", "JFA_BY", "JFA_BZ"), block))
    else:
        items, name, defines = shape_xyz, "jfa_seed_pass", {}
    gsize, lsize = grid(items, layout.group)
    kernel = gpu.programs.kernel("jfa.cl", name, JFA_STEP=step, JFA_WEIGHTED=int(weighted), JFA_WIDE=wide,
                                 JFA_FIRST=int(first), JFA_LAST=int(last), **defines)
    return kernel, gsize, lsize


def flood(gpu: GpuContext, job: RegionJob, run: AlgorithmRun, out: cl.Buffer, extra_passes: int = 0,
          piece_s: float | None = None, weighted: bool | None = None, layout: PassLayout | None = None) -> Pieces:
    """Jump flooding from the initial distances in job.buffers.work (left as they are);
    the distances found go to ``out``, a uchar box like work. Cut after each pass; with
    ``piece_s``, each pass runs in slabs of z-planes of about that long. ``weighted``: read
    seeds' weights from work (None: only where the job has seeds that weigh something)."""
    b = job.buffers
    if b.seeds is None or b.seeds2 is None:
        raise RuntimeError("jump flooding needs the world's seed buffers (World.buffer_bytes allocates them)")
    if weighted is None:
        weighted = not seeds_weigh_nothing(job)
    layout = layout or LAYOUT
    shape = job.work_box.shape_xyz
    w_n, cap, chunk = int4(shape), np.int32(job.cap), np.int32(job.chunk)
    steps = step_sizes(job, extra_passes)
    passes = steps or [0]  # a box too small for any pass: one that only finds and resolves the seeds
    wide = int(2 * max(passes) * (shape[0] * shape[1] + shape[0] + 1) >= 2 ** 31)  # a block reaches 2 steps
    vector = layout.vector and not weighted and shape[0] % 4 == 0 and job.chunk % 4 == 0
    pace = None if piece_s is None else SlabPace(piece_s, layout.group[2])
    src, dst = b.seeds, b.seeds2
    for n, step in enumerate(passes):
        seed_pass, gsize, lsize = pass_kernel(gpu, shape, step, job.chunk, layout, vector, weighted, wide,
                                              first=n == 0, last=n == len(passes) - 1)

        def launch(z0: int, planes: int, src=src, dst=dst, gsize=gsize, lsize=lsize) -> cl.Event:
            return seed_pass(gpu.queue, (gsize[0], gsize[1], planes), lsize, b.work, src, dst, out, w_n,
                             cap, chunk, global_offset=(0, 0, z0))
        yield from slabs(run, launch, gsize[2], pace)
        src, dst = dst, src
        if steps:
            run.iterations += 1
        if n < len(passes) - 1:
            yield


def flood_in_one_launch(small: OneLaunch, gpu: GpuContext, job: RegionJob, run: AlgorithmRun, plan: Plan,
                        piece_s: float | None, extra_passes: int = 0) -> Pieces:
    """``small``'s one launch with the passes ``flood`` would run (``step_sizes``)."""
    steps = step_sizes(job, extra_passes)
    main = steps[:len(steps) - extra_passes]
    yield from small.pieces(gpu, job, run, plan, piece_s, main[0] if main else 0, extra_passes)
    if not small.relax:
        run.iterations += len(steps)


class Jfa:
    exact = False
    supports_padding = True
    seed_scratch = True

    def __init__(self, extra_passes: int = 0, one_launch: bool = True) -> None:
        """``one_launch``: boxes that fit a work-group's local memory run in one launch
        (one_launch.py); False keeps a launch a pass everywhere."""
        self.extra_passes = extra_passes
        self.name = "jfa" if extra_passes == 0 else f"jfa+{extra_passes}"
        self.small = OneLaunch(flood=True, relax=False) if one_launch else None

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        run = AlgorithmRun()
        run_whole(self.pieces(gpu, job, run))
        return run

    def pieces(self, gpu: GpuContext, job: RegionJob, run: AlgorithmRun, piece_s: float | None = None) -> Pieces:
        plan = self.small and self.small.chosen(gpu, job)
        if plan:
            yield from flood_in_one_launch(self.small, gpu, job, run, plan, piece_s, self.extra_passes)
            return
        run.events.append(init_work(gpu, job, job.buffers.work))
        yield from flood(gpu, job, run, job.buffers.work2, self.extra_passes, piece_s)
        run.events.append(pack_region(gpu, job, job.buffers.work2))
