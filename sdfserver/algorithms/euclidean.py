"""euclidean — the exact Euclidean distance transform, staged so that edits stay incremental.

Computes: the exact squared Euclidean distance between voxel centres to the nearest seed,
capped at cap^2 (seeds: the solids; signed, a solid's seeds are the air voxels and the world's
outside), equal to ``scipy.ndimage.distance_transform_edt`` squared and capped.
Source: the separable transform of Meijster, Roerdink & Hesselink (2000) and Felzenszwalb &
Huttenlocher (2012): a 1-D distance along x, then lower envelopes of parabolas along z and y
(STAGE_AXES).
Kernel: kernels/edt.cl (and exact.cl's x pass), one launch a stage and box.
Units: voxels; stored squared (an integer: exact, and at most 255^2 < 2^16).
Halo: none is gathered. Each stage keeps its result world-sized between recomputes (x in the
world's ``work``, the second stage in ``edt_plane``), and an edit in box B changes the x stage only
within B grown by the cap along x, the second within B grown along x and its axis, the field
within B grown along all three (the region R): each stage rewrites its boxes, reading its input a
cap further along its axis. Incremental == full, since every stage is exact wherever it writes
and current elsewhere.
Exact: yes, across chunk borders. Failure modes: lines of up to 2048 voxels (positions are
ushort); one work-item a line, so a small box's stage runs few work-items.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sdfserver.algorithms.base import AlgorithmRun, RegionJob, WorldBuffers, _work_box, int4
from sdfserver.algorithms.exact import Exact, pass_args
from sdfserver.geometry import Box, merge_regions
from sdfserver.gpu import GpuContext

EXACT = Exact()  # its x pass is the x stage
YZ_GROUP = (64, 1)  # edt_yz: x-columns across a warp, one line each


# After x, the axes of the second and the last stage. The last reads two bytes a voxel: along y
# its lines' voxels lie a row apart, along z a whole plane (more pages a warp's loads touch).
STAGE_AXES = (2, 1)


@dataclass(frozen=True)
class StageBoxes:
    """The boxes each stage rewrites in one recompute: x, the second (STAGE_AXES[0]), the last."""

    x: list[Box]
    second: list[Box]
    last: list[Box]

    @classmethod
    def of_world(cls, size: tuple[int, int, int]) -> "StageBoxes":
        world = [Box.of_size(size)]
        return cls(world, world, world)

    @classmethod
    def of_edits(cls, boxes: list[Box], regions: list[Box], size: tuple[int, int, int], cap: int) -> "StageBoxes":
        """The stages' boxes for edits that changed voxels in ``boxes``; ``regions`` (each box grown
        by the cap and snapped to chunks) is what the last stage writes."""
        world = Box.of_size(size)

        def grown(by: tuple[int, int, int]) -> list[Box]:
            return merge_regions(dict.fromkeys(
                Box(tuple(lo - g for lo, g in zip(b.lo, by)), tuple(hi + g for hi, g in zip(b.hi, by)))
                .intersect(world) for b in boxes))

        second = [0, 0, 0]
        second[0] = second[STAGE_AXES[0]] = cap
        return cls(grown((cap, 0, 0)), grown(tuple(second)), regions)


def bytes_moved(stages: StageBoxes, cap: int, size: tuple[int, int, int]) -> int:
    """The bytes the stages must move, for achieved bandwidth: x reads the voxels over its boxes
    grown along x and writes a byte a voxel, the second stage reads bytes over its boxes grown
    along its axis and writes two, the last reads two and writes two. Signed worlds' voxel reads
    and the envelope stacks are not counted."""
    def volume(boxes: list[Box], axis: int) -> int:
        total = 0
        for b in boxes:
            n = list(b.shape_xyz)
            n[axis] = min(size[axis], b.hi[axis] + cap) - max(0, b.lo[axis] - cap)
            total += n[0] * n[1] * n[2]
        return total

    out = sum(b.volume for b in stages.x) + 2 * sum(b.volume for b in stages.second + stages.last)
    return volume(stages.x, 0) + volume(stages.second, STAGE_AXES[0]) + 2 * volume(stages.last, STAGE_AXES[1]) + out


class EuclideanExact:
    name = "exact"
    exact = True
    metric = "euclidean"

    def run_stages(self, gpu: GpuContext, buffers: WorldBuffers, field, stages: StageBoxes, cap: int,
                   signed: bool) -> AlgorithmRun:
        """Enqueue every stage over its boxes: x, then the second, then the last (each reads what
        the one before wrote, in the queue's order). ``field`` is the buffer the last writes."""
        run = AlgorithmRun(bytes_moved=bytes_moved(stages, cap, buffers.dims))
        dims, queue, sign = int4(buffers.dims), gpu.queue, int(signed)
        for box in stages.x:
            # The x stage is the Manhattan transform's x pass (a 1-D distance is the same in both
            # metrics), written in the world's layout over the box, x snapped to 8 as it needs.
            region = Box((box.lo[0] // 8 * 8, *box.lo[1:]), (min(buffers.dims[0], -(-box.hi[0] // 8) * 8), *box.hi[1:]))
            job = RegionJob.halo_region(buffers, region, cap)
            job.work_box = _work_box(buffers, Box((region.lo[0] - cap, *region.lo[1:]), (region.hi[0] + cap, *region.hi[1:])))
            for invert in (False, True) if signed else (False,):
                kernel, _, global_, local = EXACT.launch_shape(gpu, 0, job.work_box.shape_xyz[0], *job.work_box.shape_xyz,
                                                               first=True, invert=invert, world_out=True)
                run.events.append(kernel(queue, global_, local, *pass_args(job)))
        second, last = STAGE_AXES
        for axis, boxes, source, target in ((second, stages.second, buffers.work, buffers.edt_plane),
                                            (last, stages.last, buffers.edt_plane, field)):
            kernel = gpu.programs.kernel("edt.cl", "edt_yz", SIGNED=sign, AXIS=axis, LAST=int(axis == last))
            for box in boxes:
                nx, ny, nz = box.shape_xyz
                run.events.append(kernel(queue, _grid((nx, nz if axis == 1 else ny), YZ_GROUP), YZ_GROUP,
                                         source, buffers.voxels, target, buffers.edt_stack, dims,
                                         int4(box.lo), int4(box.hi), np.int32(cap)))
        return run


def _grid(n: tuple[int, int], local: tuple[int, int]) -> tuple[int, int]:
    return tuple(-(-max(1, v) // l) * l for v, l in zip(n, local))


EUCLIDEAN_EXACT = EuclideanExact()
