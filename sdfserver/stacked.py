"""Many pooled worlds' transforms in one stacked run (``gpu/slots.py``, ``Exact.run_slots``), as a
part of ``World`` (which of its recomputes can join one, and its pending recompute when it has)
and for the engine (``begin_stacked``: a step's stacked runs, one per pool)."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from sdfserver.algorithms import ALGORITHMS, AlgorithmRun, RegionJob
from sdfserver.algorithms.exact import bytes_moved
from sdfserver.gpu import GpuContext
from sdfserver.recompute import PendingRecompute

if TYPE_CHECKING:
    from sdfserver.world import World


STACKING_JOB = "stacking job"  # World._prepared's key for its whole-world job


class Stacked:
    """Mixed into ``World``, whose config, slot, dirty set and buffers it uses."""

    def stacking_job(self) -> RegionJob | None:
        """This recompute's one job where it can join its pool's stacked run (``Exact.run_slots``):
        a pooled, unsigned Manhattan world with exact borders and no focus whose algorithm is
        ``exact`` and whose dirty regions are the whole world (as under a cap near its side);
        else None."""
        cfg = self.config
        if self.slot is None or not self.dirty or cfg.algorithm != "exact" or cfg.euclidean or cfg.signed \
                or cfg.focus is not None or cfg.borders != "exact":
            return None
        regions = self.dirty_regions()
        if regions != [self.world_box] or self._lowering_boxes(regions) is not None:
            return None
        job = self._prepared.get(STACKING_JOB)  # kept with the prepared launches, gone with them
        if job is None:
            job = self._prepared[STACKING_JOB] = RegionJob.seeded_region(self.buffers, self.world_box, cfg.max_distance)
        return job

    def begin_stacked(self, run: AlgorithmRun, shared_summary: list) -> "PendingRecompute":
        """``begin_recompute`` for a world whose transform ``run`` (its share of a stacked run)
        has been enqueued for it: after ``stacking_job`` said it can join one. ``shared_summary``:
        the run's worlds' one list for its summary (``PendingRecompute.summary``)."""
        start = time.perf_counter()
        self.dirty.clear()
        return PendingRecompute(self, [self.world_box], [("exact", run)], start, self.version,
                                shared_summary=shared_summary)


def begin_stacked(gpu: GpuContext, worlds: dict[str, "World"]) -> dict[str, PendingRecompute]:
    """Start the recomputes of those of ``worlds`` that can share a stacked run (each a whole-world
    transform in a slot of one pool: ``World.stacking_job``), one run per pool that two or more
    of them share, with one cap; returns their pending recomputes, each counting its share of the run's device
    time. The others are left to ``begin_recompute``."""
    groups: dict[tuple[int, int], list] = {}  # (pool, cap): a run has one cap
    for world_id, world in worlds.items():
        job = world.stacking_job()
        if job is not None:
            groups.setdefault((id(world.slot.pool), job.cap), []).append((world_id, world, job))
    pending = {}
    for members in groups.values():
        if len(members) < 2:  # alone, its own prepared launches cost the same
            continue
        _, first, job = members[0]
        slots = [world.slot.index for _, world, _ in members]
        run = ALGORITHMS["exact"].run_slots(gpu, first.slot.pool, slots, job)
        shared = AlgorithmRun(run.events, bytes_moved=bytes_moved(job), share=1.0 / len(members))
        summary: list = []
        for world_id, world, _ in members:
            pending[world_id] = world.begin_stacked(shared, summary)
    return pending
