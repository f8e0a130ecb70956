"""fim — Fast Iterative Method (the dissertation's Algorithms 4 and 5, §4.3).

Computes: initial distances (Algorithm 4), then relaxation passes (Algorithm
5) over the whole work box until a pass changes nothing: the fixed point is
the exact distance. ``iterations`` counts the passes that changed something.
Source: Fedor 2025 §4.3; Jeong & Whitaker's FIM.
Kernel: kernels/fim.cl (+ region.cl). Convergence is read back from the
device in growing batches of passes (1, 2, 4, … 64), each pass flagging
changes in its own slot, so the count is exact while host round trips stay
few.
Units: voxels. Halo: seed shell or ``cap`` voxels; none with padded borders
(each chunk alone, its outside solid: §4.2.1). Exact: yes (padded: exactly the
per-chunk field).
Failure modes: passes grow with the distance information must travel (up to
``cap`` + the box diagonal), so large empty boxes are slow.
"""

from __future__ import annotations

import time

import numpy as np
import pyopencl as cl

from sdfserver import bulk
from sdfserver.algorithms.base import (
    AlgorithmRun, Pieces, RegionJob, grid, init_work, int4, pack_region, run_whole,
)
from sdfserver.gpu import GpuContext

MAX_BATCH = 64


def relax_pieces(gpu: GpuContext, job: RegionJob, run: AlgorithmRun, work: cl.Buffer | None = None,
                 piece_s: float | None = None) -> Pieces:
    """fim passes on ``work`` (default job.buffers.work) until one changes nothing, cut after
    each batch of passes: with ``piece_s``, a batch grows only while it is expected to take no
    longer than that (timed from the batches before it)."""
    work = job.buffers.work if work is None else work
    fim_pass = gpu.programs.kernel("fim.cl", "fim_pass")
    w_n = job.work_box.shape_xyz
    gsize, lsize = grid(w_n)
    flags = np.zeros(MAX_BATCH, dtype=np.int32)
    flag_buf = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=flags)
    try:
        batch = 1
        while True:
            started = time.perf_counter()
            bulk.fill(gpu, flag_buf, np.int32, 0, MAX_BATCH)
            for i in range(batch):
                run.events.append(fim_pass(
                    gpu.queue, gsize, lsize, work, int4(w_n), flag_buf, np.int32(i), np.int32(job.chunk)
                ))
            cl.enqueue_copy(gpu.queue, flags, flag_buf)  # waits: the batch is done
            changed = flags[:batch]
            if not changed.all():
                run.iterations += int(np.argmin(changed))
                return
            run.iterations += batch
            next_batch = batch * 2
            if piece_s is not None:
                pass_s = (time.perf_counter() - started) / batch
                next_batch = min(next_batch, max(1, int(piece_s / max(pass_s, 1e-9))))
            batch = min(MAX_BATCH, next_batch)
            yield
    finally:
        flag_buf.release()


class Fim:
    name = "fim"
    exact = True
    supports_padding = True

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        run = AlgorithmRun()
        run_whole(self.pieces(gpu, job, run))
        return run

    def pieces(self, gpu: GpuContext, job: RegionJob, run: AlgorithmRun, piece_s: float | None = None) -> Pieces:
        run.events.append(init_work(gpu, job, job.buffers.work))
        yield
        yield from relax_pieces(gpu, job, run, piece_s=piece_s)
        run.events.append(pack_region(gpu, job, job.buffers.work))
