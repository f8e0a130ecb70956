"""brute — the dissertation's Algorithms 1 and 3 (§4.1, §4.2).

Computes: for every voxel of R, the least initial distance plus Manhattan
offset over every voxel of the work box within ``cap`` on each axis.
Source: Fedor 2025, Algorithm 1 (exhaustive search) with the chunked variant
of Algorithm 3. Chunk borders are exact (seed shell) unless the world's
borders are "padded": then each voxel scans only its own chunk and everything
outside the chunk counts as solid, Algorithm 3 as written.
Kernel: kernels/brute.cl (+ region.cl to set up and pack).
Units: voxels. Halo: seed shell or ``cap`` voxels; none when padded.
Exact: yes (padded: exactly the per-chunk field).
Failure modes: O(min(W, 2 cap + 1)^3) work per voxel — seconds at 64^3 with a
large cap, hours at 512^3. For small worlds, tests and the benchmark tables.
"""

from __future__ import annotations

import numpy as np

from sdfserver.algorithms.base import AlgorithmRun, RegionJob, grid, init_work, int4, pack_region
from sdfserver.gpu import GpuContext


class Brute:
    name = "brute"
    exact = True
    supports_padding = True

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        b = job.buffers
        run = AlgorithmRun([init_work(gpu, job, b.work)])
        gsize, lsize = grid(job.region.shape_xyz)
        run.events.append(gpu.programs.kernel("brute.cl", "brute_region")(
            gpu.queue, gsize, lsize, b.work, b.work2, int4(job.work_box.shape_xyz),
            int4(job.region_offset), int4(job.region.shape_xyz), np.int32(job.cap), np.int32(job.chunk),
        ))
        run.events.append(pack_region(gpu, job, b.work2))
        return run
