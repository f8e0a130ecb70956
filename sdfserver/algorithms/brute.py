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
import pyopencl as cl

from sdfserver.algorithms.base import (
    AlgorithmRun, Pieces, RegionJob, SlabPace, grid, init_work, int4, pack_region, run_whole, slabs,
)
from sdfserver.gpu import GpuContext


class Brute:
    name = "brute"
    exact = True
    supports_padding = True

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        run = AlgorithmRun()
        run_whole(self.pieces(gpu, job, run))
        return run

    def pieces(self, gpu: GpuContext, job: RegionJob, run: AlgorithmRun, piece_s: float | None = None) -> Pieces:
        """One launch over R; with ``piece_s``, slabs of R's z-planes of about that long."""
        b = job.buffers
        run.events.append(init_work(gpu, job, b.work))
        yield
        brute = gpu.programs.kernel("brute.cl", "brute_region")
        (ox, oy, oz), (nx, ny, nz) = job.region_offset, job.region.shape_xyz

        def launch(z0: int, planes: int) -> cl.Event:
            gsize, lsize = grid((nx, ny, planes))
            return brute(gpu.queue, gsize, lsize, b.work, b.work2, int4(job.work_box.shape_xyz),
                         int4((ox, oy, oz + z0)), int4((nx, ny, planes)), np.int32(job.cap), np.int32(job.chunk))

        yield from slabs(run, launch, nz, None if piece_s is None else SlabPace(piece_s, 1))
        run.events.append(pack_region(gpu, job, b.work2))
