"""jfa — Jump Flooding (the dissertation's Algorithm 6, §4.4).

Computes: initial distances, then passes with step sizes halving from half
the box's longest side (rounded up to a power of two) down to 1; each pass
takes the six face neighbours ``step`` away plus ``step``, ping-ponging
between two buffers.
Source: Fedor 2025 §4.4; Rong & Tan 2006.
Kernel: kernels/jfa.cl (+ region.cl).
Units: voxels. Halo: seed shell or ``cap`` voxels.
Exact: no. Every candidate is a real path length, so it never underestimates
(a ray never marches through a wall); it overestimates where the shortest
path needs moves along two axes at one step size. The error is measured by
the tests and the benchmark, not assumed. (Taking all 26 neighbours, each
plus its own Manhattan length, would make it exact at 4x the reads; ``exact``
is faster still.)
"""

from __future__ import annotations

import numpy as np

from sdfserver import bulk
from sdfserver.algorithms.base import AlgorithmRun, RegionJob, grid, init_work, int4, pack_region
from sdfserver.gpu import GpuContext


def first_step(longest_side_vox: int) -> int:
    """Half the side rounded up to a power of two: steps then reach any offset in the box."""
    if longest_side_vox < 2:
        return 0
    return 1 << ((longest_side_vox - 1).bit_length() - 1)


def flood(gpu: GpuContext, job: RegionJob, run: AlgorithmRun) -> None:
    """JFA passes from job.buffers.work; the result ends in job.buffers.work."""
    jfa_pass = gpu.programs.kernel("jfa.cl", "jfa_pass")
    w_n = job.work_box.shape_xyz
    gsize, lsize = grid(w_n)
    src, dst = job.buffers.work, job.buffers.work2
    step = first_step(max(w_n))
    while step >= 1:
        run.events.append(jfa_pass(gpu.queue, gsize, lsize, src, dst, int4(w_n), np.int32(step)))
        src, dst = dst, src
        run.iterations += 1
        step //= 2
    if src is not job.buffers.work:  # an odd number of passes: bring the result home
        run.events.append(bulk.copy(gpu, job.buffers.work, src, np.uint8, job.work_box.volume))


class Jfa:
    name = "jfa"
    exact = False

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        run = AlgorithmRun([init_work(gpu, job, job.buffers.work)])
        flood(gpu, job, run)
        run.events.append(pack_region(gpu, job, job.buffers.work))
        return run
