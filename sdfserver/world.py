"""World: one chunked voxel world resident on the device.

A world owns four device buffers for its lifetime: voxels (uchar), the packed
field (ushort), and two uchar scratch boxes the algorithms work in — 5 bytes
per voxel, checked against the memory budget before anything is allocated —
and, only while an algorithm it runs floods (jfa, jfa+1, jfa+2, jfa_fim), two
uint nearest-seed buffers, 8 bytes per voxel more.
They reach 2^33 elements, so fills, copies and transfers of them go through
``sdfserver.bulk`` (the project's own 64-bit kernels, transfers in pieces).

The life of an edit: ``apply_edits`` validates a whole batch on the host,
writes it on the device (``brushes.py``) and records the boxes it may have
changed (the dirty set, ``dirty.py``); ``recompute`` consumes the dirty set —
each box grown by the cap and snapped to chunks, touching boxes merged — runs
the world's algorithm over each region, seeded from the unchanged field around
it, and returns exactly the chunks it rewrote. A voxel farther than the cap
from every change keeps its capped distance, so the result equals a full
recompute. With padded borders each chunk is computed alone, so a region is
the touched chunks only.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import pyopencl as cl

from sdfserver import bulk
from sdfserver.brushes import BRUSHES_PER_LAUNCH, WORK_ITEMS_PER_LAUNCH, enqueue_brushes, enqueue_voxels
from sdfserver.algorithms import ALGORITHMS, AlgorithmRun, WorldBuffers
from sdfserver.algorithms.base import WORK_PLANE_PAD, Pieces, int4, prepared, run_pieces
from sdfserver.algorithms.euclidean import EUCLIDEAN_EXACT, StageBoxes
from sdfserver.algorithms.region_jobs import region_jobs
from sdfserver.recompute import PendingRecompute, RecomputeResult
from sdfserver.recompute_cost import visits_per_voxel
from sdfserver.small_edits import SmallEdits
from sdfserver.stacked import Stacked
from sdfserver.dirty import SMALL_DIRTY_CHUNKS, DirtySet  # noqa: F401  (SMALL_DIRTY_CHUNKS: read by tests)
from sdfserver.edits import Edit, EditLimits, VoxelsEdit, edit_bounds, plan_brushes, validate_batch, writes
from sdfserver.errors import InvalidInput
from sdfserver.field_values import distances, needs_voxels
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext
from sdfserver.gpu.launches import KernelCopies
from sdfserver.world_config import CHUNK_SIZES, MAX_SIDE_VOX, MAX_WORLD_VOXELS, Focus, WorldConfig

PREPARED_PER_WORLD = 16  # dirty-region lists whose runs a world keeps prepared (World._launches)
# A recompute of more voxel visits than this may run in pieces (World.begin_recompute): below it,
# the wait for the device after each piece would cost more than the pause could give back.
SLICE_ABOVE_VISITS = 10_000_000



@dataclass(slots=True)
class EditPlan:
    """A validated batch and, per edit, the world-clipped boxes it may change (``World.plan_edits``).

    The engine journals a batch between planning and applying it, so that only valid
    batches are logged and each is validated once. Not frozen: one is made per batch on the
    engine thread, and a frozen dataclass sets each field through ``object.__setattr__``."""

    world: "World"
    edits: list[Edit]
    boxes: list[list[Box]]


OPTIONAL_BUFFERS = ("seeds", "seeds2", "edt_plane", "edt_stack")


def optional_sizes(config: WorldConfig) -> dict[str, int]:
    """The buffers only some worlds hold, by WorldBuffers name, in bytes: jump flooding's two
    nearest-seed boxes (uint, while an algorithm the world runs floods: ``config.floods``) and the
    Euclidean transform's second-stage box (ushort) and envelope stacks (uint), Euclidean worlds."""
    n = config.size[0] * config.size[1] * config.size[2]
    sizes = {}
    if config.floods:
        sizes.update(seeds=4 * n, seeds2=4 * n)
    if config.euclidean:
        sizes.update(edt_plane=2 * n, edt_stack=4 * n)
    return sizes


def field_defines(config: WorldConfig) -> dict[str, int]:
    """The build defines that tell field_source.h what a world's field values mean."""
    return {"FIELD_EUCLID": int(config.euclidean), "FIELD_SIGNED": int(config.signed)}


class World(SmallEdits, Stacked):
    def __init__(self, gpu: GpuContext, config: WorldConfig, limits: EditLimits = EditLimits()):
        self.config = config = config.validated()
        self.gpu = gpu
        self.limits = limits
        sx, sy, sz = config.size
        self.voxel_count = sx * sy * sz
        sizes = self.buffer_bytes(config)
        self._sizes = sizes
        # voxels, field and work in a pool's slot where one is free or can be made (gpu/slots.py)
        self.slot = gpu.slot_pools.take(config.size, sizes[:3])
        try:
            gpu.check_fits(sizes[3:] if self.slot else sizes, f"a {sx}x{sy}x{sz} world")
            own = self.gpu.allocate_all(sizes[3:4] if self.slot else sizes[:4])
        except BaseException:
            if self.slot is not None:
                gpu.slot_pools.give_back(self.slot)
            raise
        self.buffers = WorldBuffers(config.size, *(list(self.slot.buffers) + own if self.slot else own),
                                    kernels=KernelCopies())
        self._optional_sizes = optional_sizes(config)
        for name, buf in zip(self._optional_sizes, self.gpu.allocate_all(sizes[4:]) if len(sizes) > 4 else []):
            setattr(self.buffers, name, buf)
        # An empty world: every voxel air, every distance at the cap.
        bulk.fill(gpu, self.buffers.voxels, np.uint8, 0, self.voxel_count)
        if config.euclidean:  # each stage's value on air at the cap (kernels/edt.cl)
            cap = config.max_distance
            bulk.fill(gpu, self.buffers.field, np.uint16, cap * cap, self.voxel_count)
            bulk.fill(gpu, self.buffers.edt_plane, np.uint16, cap * cap, self.voxel_count)
            bulk.fill(gpu, self.buffers.work, np.uint8, cap, self.voxel_count)
        else:
            bulk.fill(gpu, self.buffers.field, np.uint16, config.max_distance << 8, self.voxel_count)
        gpu.queue.finish()
        self._dims_int4 = int4(config.size)
        self._world_box = Box.of_size(config.size)
        self.dirty = DirtySet()  # what edits may have changed since the last recompute
        # dirty regions -> their runs, prepared (_launches); emptied when the configuration changes
        self._prepared: dict[tuple[Box, ...], list[tuple[str, Callable[[], AlgorithmRun]]]] = {}
        self.version = 0  # edit batches applied
        self.field_version = 0  # the version the field reflects
        self.last_recompute: RecomputeResult | None = None  # what the last recompute did
        if config.borders == "padded":  # an empty chunk's field is its distance to its frame, not the cap
            self.dirty.mark_all()
            self.recompute()

    @staticmethod
    def buffer_bytes(config: WorldConfig) -> list[int]:
        """The device buffers a world of ``config`` holds, in bytes: voxels, field, work (a pad
        per z-plane) and work2, 5 bytes per voxel; then those of ``optional_sizes``. Nothing
        else lives as long as the world."""
        sx, sy, sz = config.size
        n = sx * sy * sz
        return [n, 2 * n, n + sz * WORK_PLANE_PAD, n] + list(optional_sizes(config).values())

    # -- lifetime -----------------------------------------------------------------------------

    def release(self) -> None:
        b = self.buffers
        if b is None:
            return
        if self.slot is not None:
            self.gpu.slot_pools.give_back(self.slot)
            self.slot = None
            self.gpu.release(b.work2, self._sizes[3])
        else:
            for buf, n in zip((b.voxels, b.field, b.work, b.work2), self._sizes):
                self.gpu.release(buf, n)
        for name, n in self._optional_sizes.items():
            self.gpu.release(getattr(b, name), n)
        self.buffers = None
        self._prepared.clear()  # their jobs hold the buffers, their kernel copies the arguments

    @property
    def device_bytes(self) -> int:
        return sum(self._sizes)

    def field_source(self) -> tuple[dict[str, int], tuple]:
        """How kernels that walk the field themselves (field_source.h's FIELD_ARGS) reach it: the
        metric and sign as build defines, and the field and voxel buffers (a sparse world passes
        its pools and brick table)."""
        return field_defines(self.config), (self.buffers.field, self.buffers.voxels)

    # -- edits ----------------------------------------------------------------------------------

    def plan_edits(self, edits: list[Edit]) -> "EditPlan":
        """Validate a batch and find the boxes it may change; changes nothing (raises on a bad batch)."""
        dims = self.config.size
        boxes = plan_brushes(edits, dims, self.limits)  # the common batch, in one pass
        if boxes is None:
            validate_batch(edits, dims, self.limits)
            boxes = [edit_bounds(e, dims, self.config.chunk_size) for e in edits]
        return EditPlan(self, edits, boxes)

    def apply_plan(self, plan: "EditPlan") -> int:
        """Write a planned batch on the device and mark its boxes dirty; returns the new version."""
        return self.apply_plans([plan])[0]

    def apply_plans(self, plans: list["EditPlan"], pooled: list | None = None) -> list[int]:
        """Write planned batches in order; returns their versions. Consecutive box and sphere
        edits, across batches, go to the device in one launch (later ones win where they
        overlap), up to BRUSHES_PER_LAUNCH: a launch costs the engine thread more host time than
        a brush costs the device. ``pooled``: a world in a slot pool leaves its last brushes
        there, (slot, brushes), for one launch with its pool's other worlds
        (``brushes.enqueue_pooled_brushes``), which must follow before anything else is enqueued."""
        versions, brushes, volume = [], [], 0
        for plan in plans:
            if plan.world is not self:
                raise ValueError("an edit plan applies only to the world that made it")
            for edit, boxes in zip(plan.edits, plan.boxes):
                if isinstance(edit, VoxelsEdit):
                    self._enqueue_brushes(brushes)  # what came before it, first
                    brushes = []
                    self._enqueue_voxels(edit)
                elif boxes:
                    box = boxes[0]
                    box_volume = box.volume
                    if len(brushes) == BRUSHES_PER_LAUNCH or volume + box_volume > WORK_ITEMS_PER_LAUNCH:
                        self._enqueue_brushes(brushes)
                        brushes, volume = [], 0
                    brushes.append((edit, box))
                    volume += box_volume
                self.dirty.add(boxes, *writes(edit))
            self.version += 1
            versions.append(self.version)
        if pooled is not None and self.slot is not None and brushes:
            pooled.append((self.slot, brushes))
        else:
            self._enqueue_brushes(brushes)
        return versions

    def apply_edits(self, edits: list[Edit]) -> int:
        """Validate and apply one batch atomically; returns the new version."""
        return self.apply_plan(self.plan_edits(edits))

    def _enqueue_voxels(self, e: VoxelsEdit) -> None:
        enqueue_voxels(self.gpu, self.buffers.voxels, self._dims_int4, self.config.size, e,
                       kernels=self.buffers.kernels)

    def _enqueue_brushes(self, batch: list[tuple[Edit, Box]]) -> None:
        enqueue_brushes(self.gpu, self.buffers.voxels, self._dims_int4, batch, kernels=self.buffers.kernels)

    def load_voxels(self, voxels: np.ndarray) -> int:
        """Replace every voxel (restore, import); the whole field becomes dirty."""
        expected = self.config.size[::-1]
        if voxels.shape != expected or voxels.dtype != np.uint8:
            raise InvalidInput(f"voxels must be uint8 with shape {expected} (z, y, x), "
                               f"got {voxels.dtype} {voxels.shape}")
        bulk.write(self.gpu, self.buffers.voxels, voxels)
        self.dirty.mark_all()
        self.version += 1
        return self.version

    # Options that change what the field holds: the next recompute rebuilds all of it.
    FIELD_CHANGES = frozenset({"algorithm", "focus", "max_distance", "lod_algorithm", "borders", "metric", "signed"})

    def reconfigure(self, **changes) -> None:
        """Change how the field is computed (the next recompute rebuilds all of it) or how it is
        placed and coloured (``voxel_size``, ``origin``, ``palette``: nothing recomputed). Seed
        and Euclidean buffers come or go with the options that need them; when they do not fit,
        nothing changes (DeviceMemoryExceeded)."""
        unknown = set(changes) - self.FIELD_CHANGES - {"voxel_size", "origin", "palette"}
        if unknown:
            raise InvalidInput(f"cannot change {sorted(unknown)} of a world")
        if changes.get("focus", None) == "keep":
            del changes["focus"]
        config = replace(self.config, **changes).validated()
        self._resize_optional(config)
        before, self.config = self.config, config
        self._prepared.clear()  # planned under the old configuration
        if any(getattr(before, k) != getattr(config, k) for k in self.FIELD_CHANGES):
            self.dirty.mark_all()

    def _resize_optional(self, config: WorldConfig) -> None:
        """Allocate or release the seed and Euclidean buffers as ``config`` needs them (raises
        before changing anything when what it needs does not fit)."""
        b, sizes = self.buffers, self.buffer_bytes(config)
        wanted = optional_sizes(config)
        adding = {name: n for name, n in wanted.items() if getattr(b, name) is None}
        if adding:
            self.gpu.check_fits(list(adding.values()), "the world's " + " and ".join(adding) + " buffers")
        dropping = [name for name in OPTIONAL_BUFFERS if name not in wanted and getattr(b, name) is not None]
        if dropping:
            self.gpu.queue.finish()  # work already queued may still read them
        for name in dropping:
            self.gpu.release(getattr(b, name), self._optional_sizes[name])
            setattr(b, name, None)
        for (name, n), buf in zip(adding.items(), self.gpu.allocate_all(list(adding.values())) if adding else []):
            setattr(b, name, buf)
        self._sizes = sizes
        self._optional_sizes = wanted

    def mark_all_dirty(self) -> None:
        """Make the next recompute rebuild the whole field (benchmarks, restores)."""
        self.dirty.mark_all()

    # -- the dirty set ----------------------------------------------------------------------------

    @property
    def world_box(self) -> Box:
        return self._world_box

    def dirty_regions(self) -> list[Box]:
        """The regions the next recompute will rewrite."""
        return self.dirty.regions(self.config)

    @property
    def dirty_chunk_count(self) -> int:
        return self.dirty.chunk_count(self.config)

    # -- recompute ----------------------------------------------------------------------------------

    def recompute(self) -> RecomputeResult:
        """Bring the field up to date with the voxels; returns the chunks rewritten."""
        return self.begin_recompute().finish()

    def begin_recompute(self, piece_s: float | None = None) -> "PendingRecompute":
        """Enqueue the recompute of everything dirty and return without waiting for the device
        (algorithms that decide on the host as they go, such as fim's convergence, wait inside):
        the engine starts every touched world's recompute, then waits for the device once.
        Nothing else may touch the world until ``finish``; the field's version moves there.

        ``piece_s``: where the world's algorithm can pause (fim, jfa, jfa_fim, brute) and the
        work is long (``SLICE_ABOVE_VISITS``), nothing is enqueued yet: the recompute is left
        to ``PendingRecompute.advance`` in pieces of about that long, so that the engine serves
        other worlds between them."""
        start = time.perf_counter()
        regions = self.dirty_regions() if self.dirty else []
        runs: list[tuple[str, AlgorithmRun]] = []
        pieces = None
        lowering = self._lowering_boxes(regions) if regions else None
        if lowering is not None:
            runs = self._lower(lowering)
        elif self.config.euclidean and regions:
            runs.append(("exact", self._compute_euclidean(self._rising_regions(regions, runs))))
        elif regions and piece_s is not None and self._runs_long(regions):
            pieces = self._pieces(regions, runs, piece_s)
        elif regions:
            runs = [(name, launch()) for name, launch in self._launches(regions)]
        self.dirty.clear()
        return PendingRecompute(self, regions, runs, start, self.version, pieces)

    def _runs_long(self, regions: list[Box]) -> bool:
        """Whether recomputing ``regions`` is work worth cutting into pieces: an algorithm that
        can pause and more than ``SLICE_ABOVE_VISITS`` voxel visits (recompute_cost's count)."""
        cfg = self.config
        names = [cfg.algorithm] + ([cfg.lod_algorithm] if cfg.focus is not None else [])
        if not any(hasattr(ALGORITHMS[n], "pieces") for n in names):
            return False
        per_voxel = max(visits_per_voxel(n, cfg) for n in names)
        return sum(r.volume for r in regions) * per_voxel > SLICE_ABOVE_VISITS

    def _pieces(self, regions: list[Box], runs: list[tuple[str, AlgorithmRun]], piece_s: float) -> Pieces:
        for region in regions:
            for algorithm, job in region_jobs(self.config, self.buffers, self.world_box, region):
                run = AlgorithmRun()
                runs.append((algorithm.name, run))
                yield from run_pieces(algorithm, self.gpu, job, run, piece_s)

    def _launches(self, regions: list[Box]) -> list[tuple[str, Callable[[], AlgorithmRun]]]:
        """The algorithm runs over ``regions``, each a call prepared once (``algorithms.base.prepared``)
        and kept while the regions repeat: under a cap near the world's side every recompute is
        the whole world, and planning it again each step cost more host time than launching it."""
        key = tuple(regions)
        found = self._prepared.get(key)
        if found is None:
            if len(self._prepared) >= PREPARED_PER_WORLD:
                self._prepared.clear()
            found = self._prepared[key] = [(algorithm.name, prepared(algorithm, self.gpu, job))
                                           for region in regions for algorithm, job in region_jobs(self.config, self.buffers, self.world_box, region)]
        return found

    def _finish_recompute(self, pending: "PendingRecompute", device_done: bool) -> RecomputeResult:
        if not device_done:
            self.gpu.queue.finish()
        self.field_version = pending.version
        each, by_algorithm, device_ms, iterations = pending.summary()
        self.last_recompute = RecomputeResult(pending.regions, self.config.chunk_size, device_ms,
                                              (time.perf_counter() - pending.started) * 1e3,
                                              iterations, each, by_algorithm)
        return self.last_recompute

    def _compute_euclidean(self, regions: list[Box]) -> AlgorithmRun:
        cfg = self.config
        stages = StageBoxes.of_world(cfg.size) if self.dirty.all else \
            StageBoxes.of_edits(self.dirty.boxes, regions, cfg.size, cfg.max_distance)
        return EUCLIDEAN_EXACT.run_stages(self.gpu, self.buffers, self.buffers.field, stages, cfg.max_distance,
                                          cfg.signed)

    # -- reads ------------------------------------------------------------------------------------

    def _read(self, buffer: cl.Buffer, dtype, box: Box | None) -> np.ndarray:
        box = self.world_box if box is None else box
        if box.empty or not self.world_box.contains(box):
            raise InvalidInput(f"box {list(box.lo)}..{list(box.hi)} is empty or outside the world "
                               f"{list(self.config.size)}")
        return bulk.read_box(self.gpu, buffer, dtype, self.config.size, box)

    def read_field(self, box: Box | None = None) -> np.ndarray:
        """The stored field, uint16, shape (z, y, x): ``(distance << 8) | colour`` in a Manhattan
        world, the squared distance in a Euclidean one (``sdfserver/field_values.py``)."""
        return self._read(self.buffers.field, np.uint16, box)

    def read_distance(self, box: Box | None = None) -> np.ndarray:
        """Distances in voxels (``field_values.distances``: uint8, int16 signed, float32 Euclidean)."""
        voxels = self.read_voxels(box) if needs_voxels(self.config) else None
        return distances(self.read_field(box), self.config, voxels)

    def read_voxels(self, box: Box | None = None) -> np.ndarray:
        return self._read(self.buffers.voxels, np.uint8, box)

    def copy_voxels_out(self) -> tuple[np.ndarray, Callable[[], None]]:
        """All voxels, (z, y, x), as they are now, without waiting for them: read the array
        only after calling the returned ``wait`` (any thread may; see
        ``bulk.download_later``)."""
        out = np.empty(self.world_box.shape_zyx, dtype=np.uint8)
        return out, bulk.download_later(self.gpu, self.buffers.voxels, out)


__all__ = ["ALGORITHMS", "CHUNK_SIZES", "MAX_SIDE_VOX", "MAX_WORLD_VOXELS", "EditPlan", "Focus", "RecomputeResult",
           "World", "WorldConfig"]
