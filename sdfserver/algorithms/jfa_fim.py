"""jfa_fim — coarse Jump Flooding refined by FIM (the dissertation's §4.5).

Computes: Algorithm 4 (initial distances), Algorithm 6 (JFA, an upper bound
close to the answer), then Algorithm 5 to convergence, which makes it exact.
``iterations`` counts the FIM passes that changed something.
Source: Fedor 2025 §4.5. Kernels: jfa.cl, fim.cl, region.cl.
Units: voxels. Halo: seed shell or ``cap`` voxels. Exact: yes.
Failure modes: as fim, with far fewer passes.
"""

from __future__ import annotations

from sdfserver.algorithms.base import AlgorithmRun, RegionJob, init_work, pack_region
from sdfserver.algorithms.fim import relax_to_convergence
from sdfserver.algorithms.jfa import flood
from sdfserver.gpu import GpuContext


class JfaFim:
    name = "jfa_fim"
    exact = True

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        run = AlgorithmRun([init_work(gpu, job, job.buffers.work)])
        flood(gpu, job, run)
        run.iterations = 0  # report FIM passes, as the dissertation's Table 4.6 does
        relax_to_convergence(gpu, job, run)
        run.events.append(pack_region(gpu, job, job.buffers.work))
        return run
