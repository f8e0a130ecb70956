"""fim — Fast Iterative Method (the dissertation's Algorithms 4 and 5, §4.3).

Computes: initial distances (Algorithm 4), then relaxation passes (Algorithm
5) over the whole work box until a pass changes nothing: the fixed point is
the exact distance. ``iterations`` counts the passes that changed something.
Source: Fedor 2025 §4.3; Jeong & Whitaker's FIM.
Kernel: kernels/fim.cl (+ region.cl). Convergence is read back from the
device in growing batches of passes (1, 2, 4, … 64), each pass flagging
changes in its own slot, so the count is exact while host round trips stay
few. A box that fits one work-group's local memory runs in one launch instead,
convergence decided on the device (one_launch.py).
Units: voxels. Halo: seed shell or ``cap`` voxels; none with padded borders
(each chunk alone, its outside solid: §4.2.1). Exact: yes (padded: exactly the
per-chunk field).
Failure modes: passes grow with the distance information must travel (up to
``cap`` + the box diagonal), so large empty boxes are slow.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import pyopencl as cl

from sdfserver import bulk
from sdfserver.algorithms.base import (
    AlgorithmRun, Pieces, RegionJob, SlabPace, grid, init_work, int4, pack_region, run_whole, slabs,
)
from sdfserver.algorithms.one_launch import OneLaunch
from sdfserver.gpu import GpuContext

MAX_BATCH = 64


def relax_pieces(gpu: GpuContext, job: RegionJob, run: AlgorithmRun, work: cl.Buffer | None = None,
                 piece_s: float | None = None) -> Pieces:
    """fim passes on ``work`` (default job.buffers.work) until one changes nothing, cut after
    each batch of passes. With ``piece_s``, each pass runs in slabs of z-planes of about that
    long (a pass relaxes in place, in any order), and a batch grows only while it is expected
    to take no longer than that."""
    work = job.buffers.work if work is None else work
    fim_pass = gpu.programs.kernel("fim.cl", "fim_pass")
    w_n = job.work_box.shape_xyz
    (gx, gy, _), lsize = grid(w_n)
    pace = None if piece_s is None else SlabPace(piece_s, lsize[2])
    flags = np.zeros(MAX_BATCH, dtype=np.int32)
    flag_buf = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=flags)

    def launch(iteration: int, z0: int, planes: int) -> cl.Event:
        return fim_pass(gpu.queue, (gx, gy, grid((1, 1, planes), lsize)[0][2]), lsize, work, int4(w_n), flag_buf,
                        np.int32(iteration), np.int32(job.chunk), global_offset=(0, 0, z0))

    try:
        batch = 1
        while True:
            bulk.fill(gpu, flag_buf, np.int32, 0, MAX_BATCH)
            for i in range(batch):
                yield from slabs(run, partial(launch, i), w_n[2], pace)
            cl.enqueue_copy(gpu.queue, flags, flag_buf)  # waits: the batch is done
            changed = flags[:batch]
            if not changed.all():
                run.iterations += int(np.argmin(changed))
                return
            run.iterations += batch
            next_batch = batch * 2
            if pace is not None:
                next_batch = min(next_batch, max(1, int(piece_s / (pace.plane_s * w_n[2]))))
            batch = min(MAX_BATCH, next_batch)
            yield
    finally:
        flag_buf.release()


class Fim:
    name = "fim"
    exact = True
    supports_padding = True

    def __init__(self, one_launch: bool = True) -> None:
        """``one_launch``: boxes that fit a work-group's local memory run in one launch
        (one_launch.py); False keeps a launch a pass everywhere."""
        self.small = OneLaunch(flood=False, relax=True) if one_launch else None

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        run = AlgorithmRun()
        run_whole(self.pieces(gpu, job, run))
        return run

    def pieces(self, gpu: GpuContext, job: RegionJob, run: AlgorithmRun, piece_s: float | None = None) -> Pieces:
        plan = self.small and self.small.chosen(gpu, job)
        if plan:
            yield from self.small.pieces(gpu, job, run, plan, piece_s)
            return
        run.events.append(init_work(gpu, job, job.buffers.work))
        yield
        yield from relax_pieces(gpu, job, run, piece_s=piece_s)
        run.events.append(pack_region(gpu, job, job.buffers.work))
