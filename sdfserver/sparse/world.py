"""SparseWorld: a world whose bricks live in pools, only where they hold something.

A brick is one chunk. Bricks that are all air at the cap, or all solid of one colour, are
implicit (a code in the host's brick table, ``table.py``); the others take a slot in the brick
pools (``pool.py``, 3 bytes a stored voxel). Everything else is the dense world's:

- An edit batch is validated and its boxes found as for a dense world; its worst case — every
  implicit brick of the regions it would make dirty becoming stored — is reserved in the pools
  before the batch is accepted, so a batch that cannot fit is refused whole
  (DeviceMemoryExceeded, 507) and a recompute never runs out halfway.
- ``recompute``: the dirty boxes become regions exactly as in a dense world (grown by the cap,
  snapped to chunks, touching ones merged). Each region R is GATHERED, with a shell around it,
  into a dense scratch box (stored bricks copied, implicit ones written as their value); the
  pending edits are written into it with the dense world's brush kernels (world coordinates, the
  box's origin passed along); the world's algorithm runs on it as a seeded RegionJob, the same
  code path as a dense world; then R's bricks are CLASSIFIED (mixed, all air at the cap, all one
  solid colour) and SCATTERED: mixed bricks keep or get a slot, uniform ones give theirs back.
- The shell is one voxel along y and z and 8 along x (rows load as aligned vectors, as
  ``RegionJob``'s work box asks); its field is final, so the region is exact (docs/algorithms.md).

Every step costs in proportion to its regions: nothing walks the brick grid or the pools,
except a pool growth, which copies the stored bricks once (``pool.py``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import pyopencl as cl

from sdfserver.algorithms import RegionJob, WorldBuffers, get_algorithm
from sdfserver.algorithms.base import WORK_PLANE_PAD, int4
from sdfserver.algorithms.euclidean import EUCLIDEAN_EXACT, StageBoxes
from sdfserver.algorithms.stats import summarize
from sdfserver.brushes import enqueue_brushes, enqueue_voxels
from sdfserver.dirty import DirtySet
from sdfserver.edits import Edit, EditLimits, VoxelsEdit, edit_bounds, validate_batch
from sdfserver.errors import DeviceMemoryExceeded, InvalidInput, TooLarge
from sdfserver.field_values import distances, needs_voxels
from sdfserver.geometry import Box, merge_regions
from sdfserver.gpu import GpuContext
from sdfserver.sparse import kernels
from sdfserver.sparse.device_table import DeviceTable
from sdfserver.sparse.pool import BYTES_PER_STORED_VOXEL, BrickPool
from sdfserver.sparse.snapshots import SparseSnapshots
from sdfserver.sparse.table import AIR, BrickTable, solid_code
from sdfserver.world import BRUSHES_PER_LAUNCH, EditPlan, RecomputeResult, field_defines
from sdfserver.world_config import MAX_SIDE_VOX, WorldConfig

SHELL_X_VOX = 8  # the shell's width along x: RegionJob widens work boxes to multiples of 8
# A dense world puts more than 32 regions of a step into one box around them all; in a sparse
# world edits far apart would make that box larger than the world's memory, so it keeps more.
MAX_REGIONS = 512


@dataclass(frozen=True)
class DoneRecompute:
    """``World.begin_recompute``'s answer for a recompute already finished."""

    result: RecomputeResult
    in_pieces = False

    def finish(self, device_done: bool = False) -> RecomputeResult:
        return self.result


class SparseWorld(SparseSnapshots):
    def __init__(self, gpu: GpuContext, config: WorldConfig, limits: EditLimits = EditLimits(),
                 generate: bool = True, segment_bricks: int | None = None):
        """``generate``: build ``config.generate``'s terrain (not when a snapshot replaces it).
        ``segment_bricks``: bricks a pool segment holds (default: what the device's largest
        buffer holds; smaller in tests, to cross segments)."""
        self.config = config = config.validated()
        if config.storage != "sparse":
            raise ValueError("SparseWorld is for storage 'sparse'")
        if config.floods:
            raise InvalidInput("a sparse world runs an algorithm without seed buffers (not jfa, jfa+1, "
                               "jfa+2 or jfa_fim)")
        if config.generate is not None and (config.euclidean or config.signed):
            raise InvalidInput("generate (a terrain) is for Manhattan, unsigned sparse worlds; create the world "
                               "Euclidean or signed without it and write voxels")
        self.gpu, self.limits = gpu, limits
        self.brick = config.chunk_size
        # Every edit needs a scratch box of at least one brick grown by the cap: refuse a world
        # that could not take even that, before anything is allocated.
        side = self.brick + 2 * (-(-config.max_distance // self.brick) * self.brick)
        smallest = tuple(min(side + 2 * (-(-config.max_distance // SHELL_X_VOX) * SHELL_X_VOX
                                         if config.euclidean else SHELL_X_VOX), v) for v in config.size)
        gpu.check_fits(self._scratch_sizes(smallest[0] * smallest[1] * smallest[2], smallest[2]),
                       f"a sparse {'x'.join(map(str, config.size))} world's scratch box")
        self.table = BrickTable(config.chunks)
        self.classify_results = kernels.ClassifyResults(gpu)  # kept between recomputes (terrain tiles too)
        self.pool = BrickPool(gpu, self.brick, segment_bricks)
        self.scratch: WorldBuffers | None = None
        self._scratch_sizes_held: list[int] = []
        self.dirty = DirtySet()
        self.pending: list[tuple[Edit, list[Box]]] = []  # applied, not yet written: recompute writes them
        self.switched_regions: list[Box] = []  # rewritten by a metric or sign switch, not yet published
        self.reserved: list[Box] = []  # boxes of planned batches whose room is reserved
        self.version = 0
        self.field_version = 0
        self.last_recompute: RecomputeResult | None = None
        self.buffers = None  # no world-sized buffers: readers gather (read_field, read_voxels)
        self.device_table = DeviceTable(gpu, self.table)
        if config.generate is not None and generate:
            from sdfserver.sparse.terrain import generate_terrain  # it builds on this class

            try:
                generate_terrain(self, config.generate)
            except BaseException:
                self.release()
                raise

    # -- memory ------------------------------------------------------------------------------

    def _scratch_sizes(self, voxels: int, planes: int) -> list[int]:
        """voxels, field, work, work2 and, Euclidean, the transform's y-stage and stack boxes."""
        return [voxels, 2 * voxels, voxels + planes * WORK_PLANE_PAD, voxels] + \
            ([2 * voxels, 4 * voxels] if self.config.euclidean else [])

    def _ensure_scratch(self, voxels: int) -> None:
        """Hold a scratch box of at least ``voxels`` voxels; raises DeviceMemoryExceeded, keeping
        the one held, when a larger one does not fit (it replaces the one held)."""
        if self.scratch is not None and self._scratch_sizes_held[0] >= voxels \
                and len(self._scratch_sizes_held) == len(self._scratch_sizes(1, 1)):  # a metric switch changes them
            return
        sizes = self._scratch_sizes(voxels, MAX_SIDE_VOX)
        free = self.gpu.memory_budget_bytes - self.gpu.allocated_bytes + sum(self._scratch_sizes_held)
        if sum(sizes) > free or max(sizes) > self.gpu.max_allocation_bytes:
            raise DeviceMemoryExceeded(
                f"a sparse world's scratch box of {voxels} voxels needs {sum(sizes) / 2**20:.0f} MiB "
                f"(at most {self.gpu.max_allocation_bytes / 2**20:.0f} MiB a buffer); "
                f"{free / 2**20:.0f} MiB of the budget is free for it")
        self._release_scratch()
        buffers = self.gpu.allocate_all(sizes)
        self.scratch = WorldBuffers((0, 0, 0), *buffers[:4])
        if len(buffers) > 4:
            self.scratch.edt_plane, self.scratch.edt_stack = buffers[4:]
        self._scratch_sizes_held = sizes

    def _release_scratch(self) -> None:
        if self.scratch is not None:
            self.gpu.queue.finish()
            s = self.scratch
            for buf, n in zip((s.voxels, s.field, s.work, s.work2, s.edt_plane, s.edt_stack), self._scratch_sizes_held):
                self.gpu.release(buf, n)
        self.scratch, self._scratch_sizes_held = None, []

    def release(self) -> None:
        self._release_scratch()
        self.classify_results.release()
        self.pool.release()
        self.device_table.release()

    def field_source(self) -> tuple[dict[str, int], tuple]:
        """How kernels that walk the field themselves (render.cl) reach it: their build defines
        and the arguments FIELD_ARGS stands for."""
        top, blocks = self.device_table.current()
        fields = self.pool.kernel_buffers("field") or (top,) * 4  # no stored brick: none is read
        voxels = self.pool.kernel_buffers("voxels") or (top,) * 4
        return {"SPARSE_FIELD": 1, **field_defines(self.config)}, (
            *fields, *voxels, np.int32(self.pool.segment_bricks), top, blocks,
                                     int4(self.device_table.top_n), np.int32(self.brick),
                                     np.int32(self.config.max_distance))

    @property
    def device_bytes(self) -> int:
        return self.pool.device_bytes + sum(self._scratch_sizes_held)

    @property
    def stored_bricks(self) -> int:
        return self.pool.stored

    @property
    def bytes_per_stored_voxel(self) -> float | None:
        """Device bytes (pools with their free slots, scratch) over stored voxels; None with none
        stored."""
        stored = self.pool.stored * self.brick ** 3
        return self.device_bytes / stored if stored else None

    def reconfigure(self, **changes) -> None:
        """Where the world lies and how it is coloured change alone; a new metric or sign
        recomputes every brick within the cap of a solid (``switch_field``). The algorithm, cap and
        borders are fixed at creation."""
        fixed = sorted(set(changes) - {"voxel_size", "origin", "palette", "metric", "signed"})
        if fixed:
            raise InvalidInput(f"a sparse world's {', '.join(fixed)} cannot change (algorithm, cap and borders "
                               f"are fixed at creation); metric, signed, voxel_size, origin and palette can")
        config = replace(self.config, **changes).validated()
        if (config.metric, config.signed) != (self.config.metric, self.config.signed):
            from sdfserver.sparse.switch import switch_field  # it builds on this class

            switch_field(self, config)
        else:
            self.config = config

    def mark_all_dirty(self) -> None:
        raise InvalidInput("a sparse world recomputes the regions its edits touch, never the whole world")

    # -- geometry -------------------------------------------------------------------------------

    @property
    def world_box(self) -> Box:
        return Box.of_size(self.config.size)

    def scratch_box(self, region: Box, halo: bool = False) -> Box:
        """The dense box a region is computed in: the region and its seed shell, in the world (a
        Euclidean field is not seeded by the field around, nor is a region computed ``halo``: the
        region and a halo of the cap)."""
        lo, hi = region.lo, region.hi
        if self.config.euclidean or halo:  # x by whole 8s: the x stage loads rows as aligned 8-voxel vectors
            cap = self.config.max_distance
            halo_x = -(-cap // SHELL_X_VOX) * SHELL_X_VOX
            return Box((lo[0] - halo_x, lo[1] - cap, lo[2] - cap),
                       (hi[0] + halo_x, hi[1] + cap, hi[2] + cap)).intersect(self.world_box)
        return Box((lo[0] - SHELL_X_VOX, lo[1] - 1, lo[2] - 1),
                   (hi[0] + SHELL_X_VOX, hi[1] + 1, hi[2] + 1)).intersect(self.world_box)

    def dirty_regions(self) -> list[Box]:
        return self.dirty.regions(self.config, MAX_REGIONS)

    @property
    def dirty_chunk_count(self) -> int:
        return self.dirty.chunk_count(self.config)

    # -- edits ---------------------------------------------------------------------------------

    def plan_edits(self, edits: list[Edit]) -> EditPlan:
        """Validate a batch and reserve room for its worst case; raises (InvalidEdit, TooLarge,
        DeviceMemoryExceeded) with the world unchanged."""
        validate_batch(edits, self.config.size, self.limits)
        boxes = [edit_bounds(e, self.config.size, self.brick) for e in edits]
        every = DirtySet()
        every.add(self.dirty.boxes + self.reserved + [b for per_edit in boxes for b in per_edit])
        regions = every.regions(self.config, MAX_REGIONS)
        implicit, largest = 0, 0
        for region in regions:  # one loop over regions
            scratch = self.scratch_box(region)
            if max(scratch.shape_xyz) > MAX_SIDE_VOX:
                raise TooLarge(f"a sparse world recomputes at most {MAX_SIDE_VOX} voxels a side at once; "
                               f"this batch, with the edits pending, makes a region of {list(region.shape_xyz)}")
            implicit += int((self.table.get(region.chunk_range(self.brick)) < 0).sum())
            largest = max(largest, scratch.volume)
        self.pool.reserve(implicit)
        self._ensure_scratch(largest)
        self.reserved.extend(b for per_edit in boxes for b in per_edit)
        return EditPlan(self, edits, boxes)

    def apply_plan(self, plan: EditPlan) -> int:
        return self.apply_plans([plan])[0]

    def apply_plans(self, plans: list[EditPlan], pooled: list | None = None) -> list[int]:
        """Accept planned batches in order: they are written into the scratch box at the next
        recompute, each region's edits in order. Returns their versions. ``pooled`` is for
        dense worlds in slot pools (``World.apply_plans``): a sparse world takes no slot."""
        versions = []
        for plan in plans:
            if plan.world is not self:
                raise ValueError("an edit plan applies only to the world that made it")
            for edit, boxes in zip(plan.edits, plan.boxes):
                if boxes:
                    self.pending.append((edit, boxes))
                    self.dirty.add(boxes)
            self.version += 1
            versions.append(self.version)
        return versions

    def apply_edits(self, edits: list[Edit]) -> int:
        return self.apply_plan(self.plan_edits(edits))

    def _write_edits(self, region: Box, box: Box) -> None:
        """Write the pending edits that fall in ``region`` into the scratch box ``box``, in order."""
        s, dims, origin = self.scratch, int4(box.shape_xyz), int4(box.lo)
        brushes: list[tuple[Edit, Box]] = []
        for edit, boxes in self.pending:  # one loop over the step's edits
            if isinstance(edit, VoxelsEdit):
                xyz = edit.voxels[:, :3]
                inside = ((xyz >= region.lo) & (xyz < region.hi)).all(axis=1)
                if inside.any():
                    enqueue_brushes(self.gpu, s.voxels, dims, brushes, origin)
                    brushes = []
                    enqueue_voxels(self.gpu, s.voxels, dims, self.config.size, VoxelsEdit(edit.voxels[inside]), origin)
                continue
            clipped = boxes[0].intersect(region)
            if clipped.empty:
                continue
            if len(brushes) == BRUSHES_PER_LAUNCH:
                enqueue_brushes(self.gpu, s.voxels, dims, brushes, origin)
                brushes = []
            brushes.append((edit, clipped))
        enqueue_brushes(self.gpu, s.voxels, dims, brushes, origin)

    # -- recompute -----------------------------------------------------------------------------

    def stacking_job(self) -> None:
        """Never: a sparse world's bricks are not in a slot pool (``sdfserver/stacked.py``)."""
        return None

    def begin_recompute(self, piece_s: float | None = None) -> "DoneRecompute":
        """A sparse world's recompute waits for the device as it goes (each region's bricks are
        classified on the host), so it is done when this returns; it does not run in pieces
        (``piece_s`` is not used): its regions share one scratch box of at most
        ``MAX_SIDE_VOX`` a side, bounded by the recompute cost limit."""
        return DoneRecompute(self.recompute())

    def recompute(self) -> RecomputeResult:
        start = time.perf_counter()
        regions = self.dirty_regions() if self.dirty else []
        # what a metric or sign switch rewrote this step (switch_field): published with this result
        switched, self.switched_regions = self.switched_regions, []
        runs = []
        algorithm, cap = get_algorithm(self.config.algorithm), self.config.max_distance
        for region in regions:  # one loop over regions; each launches a fixed number of kernels
            runs.append((algorithm.name, self._compute_region(region, algorithm, cap)))
        self.gpu.queue.finish()
        self.dirty.clear()
        self.pending.clear()
        self.reserved.clear()
        self.field_version = self.version
        each, by_algorithm = summarize(runs)
        self.last_recompute = RecomputeResult(merge_regions(switched + regions, MAX_REGIONS) if switched else regions, self.brick, sum(each), (time.perf_counter() - start) * 1e3,
                                              sum(run.iterations for _, run in runs), each, by_algorithm)
        return self.last_recompute

    def _compute_region(self, region: Box, algorithm, cap: int, halo: bool = False):
        """``halo``: from the voxels alone (a switch of metric or sign, where the field around is
        still the old one's)."""
        box = self.scratch_box(region, halo)
        self._ensure_scratch(box.volume)  # reserved when the batch was planned: allocates nothing
        s = self.scratch
        bricks = box.chunk_range(self.brick)
        defines = field_defines(self.config)
        kernels.gather(self.gpu, self.pool, bricks, self.table.get(bricks), s.voxels, s.field, box, cap, self.brick,
                       defines)
        self._write_edits(region, box)
        local = Box(tuple(r - b for r, b in zip(region.lo, box.lo)), tuple(r - b for r, b in zip(region.hi, box.lo)))
        view = WorldBuffers(box.shape_xyz, s.voxels, s.field, s.work, s.work2, edt_plane=s.edt_plane,
                            edt_stack=s.edt_stack)
        if self.config.euclidean:  # the box holds R and a halo of the cap: every stage over all of it
            run = EUCLIDEAN_EXACT.run_stages(self.gpu, view, s.field, StageBoxes.of_world(box.shape_xyz), cap,
                                             self.config.signed)
        else:
            make_job = RegionJob.halo_region if halo else RegionJob.seeded_region
            job = replace(make_job(view, local, cap), signed=self.config.signed,
                          world=Box(tuple(-v for v in box.lo), tuple(s - v for s, v in zip(self.config.size, box.lo))))
            run = algorithm.run(self.gpu, job)
            if self.config.signed:
                run.events += algorithm.run(self.gpu, replace(job, invert=True)).events
        mixed, first = kernels.classify(self.gpu, s.voxels, s.field, box.shape_xyz, local, cap, self.brick,
                                        self.classify_results, defines)
        region_bricks = region.chunk_range(self.brick)
        old = self.table.get(region_bricks)
        new = np.where(first == 0, AIR, solid_code(first)).astype(np.int32)
        kept = mixed & (old >= 0)
        new[kept] = old[kept]
        fresh = mixed & (old < 0)
        new[fresh] = self.pool.take(int(fresh.sum()))
        kernels.scatter(self.gpu, self.pool, s.voxels, s.field, box, region, region_bricks, new, self.brick)
        self.pool.give(old[(old >= 0) & ~mixed])
        self.table.set(region_bricks, new)
        return run

    # -- reads -----------------------------------------------------------------------------------

    def _gather_box(self, box: Box | None) -> tuple[np.ndarray, np.ndarray]:
        box = self.world_box if box is None else box
        if box.empty or not self.world_box.contains(box):
            raise InvalidInput(f"box {list(box.lo)}..{list(box.hi)} is empty or outside the world "
                               f"{list(self.config.size)}")
        n = box.volume
        self.gpu.check_fits([n, 2 * n], f"a read of {list(box.shape_xyz)} voxels")
        voxels_buf, field_buf = self.gpu.allocate(n), self.gpu.allocate(2 * n)
        try:
            bricks = box.chunk_range(self.brick)
            kernels.gather(self.gpu, self.pool, bricks, self.table.get(bricks), voxels_buf, field_buf, box,
                           self.config.max_distance, self.brick, field_defines(self.config))
            voxels = np.empty(box.shape_zyx, dtype=np.uint8)
            field = np.empty(box.shape_zyx, dtype=np.uint16)
            cl.enqueue_copy(self.gpu.queue, voxels, voxels_buf)
            cl.enqueue_copy(self.gpu.queue, field, field_buf, is_blocking=True)
        finally:
            self.gpu.release(voxels_buf, n)
            self.gpu.release(field_buf, 2 * n)
        return voxels, field

    def read_field(self, box: Box | None = None) -> np.ndarray:
        """The stored field, uint16, shape (z, y, x): what its values mean follows the metric and
        sign (``sdfserver/field_values.py``); implicit bricks read as their value."""
        return self._gather_box(box)[1]

    def read_distance(self, box: Box | None = None) -> np.ndarray:
        """Distances in voxels (``field_values.distances``: uint8, int16 signed, float32 Euclidean)."""
        voxels = self.read_voxels(box) if needs_voxels(self.config) else None
        return distances(self.read_field(box), self.config, voxels)

    def read_voxels(self, box: Box | None = None) -> np.ndarray:
        return self._gather_box(box)[0]


__all__ = ["BYTES_PER_STORED_VOXEL", "SparseWorld"]
