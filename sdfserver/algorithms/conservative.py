"""conservative — a lower bound of the distance from a coarse grid of bricks: the safe LOD.

Computes: over R, a field that is 0 (with the voxel's colour) exactly on solids and, on air,
at least 1 and never above the true capped Manhattan distance, so a ray that steps by it never
passes a solid (docs/rendering.md): frames show the same voxels as with the exact field.
Meant for ``lod_algorithm`` (outside a focus), where the dissertation's §4.6 uses JFA, whose
field is never below the truth and so can let rays step over thin solids (Figure 4.9).
Source: not in the dissertation; a coarse level (as in hierarchical distance fields) whose
per-axis brick offsets bound the voxel offsets.
Kernel: kernels/conservative.cl, five launches: brick_init (one work-item per brick, reads the
work box's voxels once), three brick_pass (one work-item per coarse line), brick_pack (one
work-item per voxel of R, reads its voxel and its brick's value, writes the field). Coarse
work is O(W / BRICK^3); the per-voxel work is one read pass over W and one write pass over R,
against exact's three read-write passes over W.
Units: voxels; bricks of BRICK^3 voxels (8, or 4) on the world's grid. Halo: the seed shell
(seeded) or ``cap`` voxels (halo), as every algorithm (base.py). Exact: no — a lower bound.

Why it is a lower bound. Let b = BRICK, R the region, W the work box, p in R in brick P.
1. Let base(q) be init_distance over W: 0 on solids, the current field on the seed shell,
   else "cap". For any solid s nearest to p, either s is in W (base(s) = 0), or the shortest
   path from p to s crosses the shell at some q with |p - q| + D(q) <= |p - s| (seeded), or
   |p - s| > cap (halo: W is R grown by cap). So, when the field on the shell never exceeds
   the truth, D_cap(p) >= min(cap, min over q in W of base(q) + |p - q|).
2. For q in brick Q: on an axis a where the bricks differ by k = |P_a - Q_a| >= 1, the voxels
   lie at least (k - 1) b + 1 apart (e.g. Q_a > P_a: q_a >= Q_a b, p_a <= P_a b + b - 1). With
   h(0) = 0, h(k) = (k - 1) b + 1, |p - q| >= sum over a of h(|P_a - Q_a|); and
   base(q) >= init(Q), the least base over Q's voxels in W (brick_init).
3. So D_cap(p) >= C(P) = min(cap, min over Q of init(Q) + sum_a h(|P_a - Q_a|)). The kernel is
   a sum of one function per axis, so C is three 1-D min-plus transforms, one per axis
   (brick_pass), each exact with kernel h: out[i] = min(d[i], min over j != i of
   d[j] + b |i - j| - (b - 1)), a forward and a backward sweep. Capping at cap between passes
   keeps min-plus exact for the capped result (h >= 0).
4. Air has D >= 1, so max(1, C(P)) is a lower bound too; solids get 0 (brick_pack).
Hence every voxel's value is at most the truth, and a ray's skip of d steps from a voxel whose
field is d stays within d of it: it never steps over a solid.

Known failure modes: the bound is loose near solids (air in a brick holding a solid reads 1,
two bricks away at least b + 1), so rays take more, shorter steps than with the exact field,
and ambient occlusion and soft shadows, which read distance values, come out darker than with
the exact field (hit voxels, faces and colours are the same). Point 1 needs the seed shell's
field to be a lower bound: true when every other part of the field comes from this algorithm
or an exact one; with ``jfa`` as the world's algorithm inside a focus, the shell can hold
overestimates and the bound can fail near the focus. Incremental results depend on the seed
shell, so they can differ from a full recompute (both are lower bounds).
"""

from __future__ import annotations

import numpy as np

from sdfserver.algorithms.base import AlgorithmRun, RegionJob, grid, int4
from sdfserver.gpu import GpuContext

BRICK_VOX = 8  # world sides are multiples of 8 (the smallest chunk), so bricks tile the world
BRICK_SIZES = (4, 8)
LINE_GROUP = (8, 8)  # work-items per group for the coarse line passes


class Conservative:
    name = "conservative"
    exact = False

    def __init__(self, brick_vox: int = BRICK_VOX) -> None:
        if brick_vox not in BRICK_SIZES:
            raise ValueError(f"brick_vox must be one of {BRICK_SIZES}, got {brick_vox!r}")
        self.brick_vox = brick_vox

    def coarse_box(self, job: RegionJob) -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        """The bricks that meet the work box: origin and extent, in bricks."""
        b = self.brick_vox
        lo = tuple(v // b for v in job.work_box.lo)
        hi = tuple(-(-v // b) for v in job.work_box.hi)
        return lo, tuple(h - l for l, h in zip(lo, hi))

    def _kernels(self, gpu: GpuContext):
        return lambda name: gpu.programs.kernel("conservative.cl", name, BRICK=self.brick_vox)

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun:
        buffers, w, r, cap, b = job.buffers, job.work_box, job.region, np.int32(job.cap), self.brick_vox
        c_lo, c_n = self.coarse_box(job)
        kernel = self._kernels(gpu)
        # Stages ping-pong between the scratch buffers; each holds at most one byte per world
        # voxel, since bricks never pass the world's sides (multiples of 8).
        run = AlgorithmRun()
        gsize, lsize = grid(c_n)
        run.events.append(kernel("brick_init")(
            gpu.queue, gsize, lsize, buffers.voxels, buffers.field, buffers.work, int4(buffers.dims),
            int4(w.lo), int4(w.hi), int4(r.lo), int4(r.hi), int4(c_lo), int4(c_n),
            np.int32(job.seeded), cap))
        x_n = (c_n[0] * b, c_n[1], c_n[2])
        for axis, src, dst, s_n, lines in ((0, buffers.work, buffers.work2, c_n, (c_n[1], c_n[2])),
                                          (1, buffers.work2, buffers.work, x_n, (x_n[0], x_n[2]))):
            run.events.append(kernel("brick_spread")(gpu.queue, *_lines(lines), src, dst, int4(s_n),
                                                     np.int32(axis), cap))
        y_n = (c_n[0] * b, c_n[1] * b, c_n[2])
        v_lo = tuple(v * b for v in c_lo)
        run.events.append(kernel("brick_pack")(
            gpu.queue, *_lines(r.shape_xyz[:2]), buffers.work, buffers.work2, buffers.voxels, buffers.field,
            int4(buffers.dims), int4(y_n), int4(v_lo), int4(r.lo), int4(r.shape_xyz), cap))
        return run


def _lines(shape_uv: tuple[int, int]):
    """Global and local size for one work-item per line of a (u, v) grid of lines."""
    return tuple(-(-max(1, n) // l) * l for n, l in zip(shape_uv, LINE_GROUP)), LINE_GROUP
