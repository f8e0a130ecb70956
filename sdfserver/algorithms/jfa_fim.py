"""jfa_fim — coarse Jump Flooding refined by FIM (the dissertation's §4.5).

Computes: Algorithm 4 (initial distances), Algorithm 6 (jump flooding, an
upper bound close to the answer: see jfa.py), then Algorithm 5 to
convergence, which makes it exact: relaxation from any upper bound that is
no higher than the initial distances ends at the least fixed point.
``iterations`` counts the FIM passes that changed something.
Source: Fedor 2025 §4.5. Kernels: jfa.cl, fim.cl, region.cl.
Units: voxels. Halo: seed shell or ``cap`` voxels; none with padded borders.
Exact: yes (padded: exactly the per-chunk field). Scratch: jfa's seed buffers.
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
    supports_padding = True
    seed_scratch = True

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        b = job.buffers
        run = AlgorithmRun([init_work(gpu, job, b.work)])
        flood(gpu, job, run, b.work2)
        run.iterations = 0  # report FIM passes, as the dissertation's Table 4.6 does
        relax_to_convergence(gpu, job, run, b.work2)
        run.events.append(pack_region(gpu, job, b.work2))
        return run
