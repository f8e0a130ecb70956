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

import numpy as np
import pyopencl as cl

from sdfserver import bulk
from sdfserver.algorithms.base import AlgorithmRun, RegionJob, grid, init_work, int4, pack_region
from sdfserver.gpu import GpuContext

MAX_BATCH = 64


def relax_to_convergence(gpu: GpuContext, job: RegionJob, run: AlgorithmRun,
                         work: cl.Buffer | None = None) -> None:
    """Run fim passes on ``work`` (default job.buffers.work) until one changes nothing."""
    work = job.buffers.work if work is None else work
    fim_pass = gpu.programs.kernel("fim.cl", "fim_pass")
    w_n = job.work_box.shape_xyz
    gsize, lsize = grid(w_n)
    flags = np.zeros(MAX_BATCH, dtype=np.int32)
    flag_buf = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=flags)
    try:
        batch = 1
        while True:
            bulk.fill(gpu, flag_buf, np.int32, 0, MAX_BATCH)
            for i in range(batch):
                run.events.append(fim_pass(
                    gpu.queue, gsize, lsize, work, int4(w_n), flag_buf, np.int32(i), np.int32(job.chunk)
                ))
            cl.enqueue_copy(gpu.queue, flags, flag_buf)
            changed = flags[:batch]
            if not changed.all():
                run.iterations += int(np.argmin(changed))
                return
            run.iterations += batch
            batch = min(MAX_BATCH, batch * 2)
    finally:
        flag_buf.release()


class Fim:
    name = "fim"
    exact = True
    supports_padding = True

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        run = AlgorithmRun([init_work(gpu, job, job.buffers.work)])
        relax_to_convergence(gpu, job, run)
        run.events.append(pack_region(gpu, job, job.buffers.work))
        return run
