"""jfa_fim — coarse Jump Flooding refined by FIM (the dissertation's §4.5).

Computes: Algorithm 4 (initial distances), Algorithm 6 (jump flooding, an
upper bound close to the answer: see jfa.py), then Algorithm 5 to
convergence, which makes it exact: relaxation from any upper bound that is
no higher than the initial distances ends at the least fixed point.
``iterations`` counts the FIM passes that changed something.
Source: Fedor 2025 §4.5. Kernels: jfa.cl, fim.cl, region.cl.
Units: voxels. Halo: seed shell or ``cap`` voxels; none with padded borders.
Exact: yes (padded: exactly the per-chunk field). Scratch: jfa's seed buffers.
A box that fits one work-group's local memory runs both in one launch
(one_launch.py).
Failure modes: as fim, with far fewer passes.
"""

from __future__ import annotations

from sdfserver.algorithms.base import AlgorithmRun, Pieces, RegionJob, init_work, pack_region, run_whole
from sdfserver.algorithms.fim import relax_pieces
from sdfserver.algorithms.jfa import flood, flood_in_one_launch
from sdfserver.algorithms.one_launch import OneLaunch
from sdfserver.gpu import GpuContext


class JfaFim:
    name = "jfa_fim"
    exact = True
    supports_padding = True
    seed_scratch = True

    def __init__(self, one_launch: bool = True) -> None:
        """``one_launch``: boxes that fit a work-group's local memory run in one launch
        (one_launch.py); False keeps a launch a pass everywhere."""
        self.small = OneLaunch(flood=True, relax=True) if one_launch else None

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        run = AlgorithmRun()
        run_whole(self.pieces(gpu, job, run))
        return run

    def pieces(self, gpu: GpuContext, job: RegionJob, run: AlgorithmRun, piece_s: float | None = None) -> Pieces:
        plan = self.small and self.small.chosen(gpu, job)
        if plan:  # iterations: the FIM passes the device counts, as below
            yield from flood_in_one_launch(self.small, gpu, job, run, plan, piece_s)
            return
        b = job.buffers
        run.events.append(init_work(gpu, job, b.work))
        yield from flood(gpu, job, run, b.work2, piece_s=piece_s)
        run.iterations = 0  # report FIM passes, as the dissertation's Table 4.6 does
        yield from relax_pieces(gpu, job, run, b.work2, piece_s)
        run.events.append(pack_region(gpu, job, b.work2))
