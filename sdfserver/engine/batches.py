"""Edit batches through one step: plan (validate against the world; a bad batch fails alone,
nothing logged or applied) -> journal (each world's batches of the step in one log record) ->
apply (the step's brushes in few launches) -> acknowledge (each batch with its version, once the
log has it on disk).

A batch that carries the client's id (``Idempotency-Key``) is remembered with its version once
acknowledged (the last ``REMEMBERED_BATCHES`` of each world; rebuilt from the log at start-up):
the same id again is answered with that version and not applied again, so a client may retry a
batch whose answer it never got (an engine restarted under it) without doubling it."""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from concurrent.futures import Future
from typing import Any, Callable

import pyopencl as cl

from sdfserver.brushes import enqueue_pooled_brushes
from sdfserver.engine.commands import ApplyEdits, StepReport
from sdfserver.engine.journal import Journal
from sdfserver.engine.metrics import EngineMetrics
from sdfserver.engine.worlds import WorldTable
from sdfserver.errors import SdfServerError
from sdfserver.world import EditPlan

log = logging.getLogger("sdfserver.engine")
Planned = tuple[ApplyEdits, Future, EditPlan]
REMEMBERED_BATCHES = 4096  # ids per world: a retry comes within seconds of its first attempt


def fail(future: Future, exc: BaseException) -> None:
    """Complete ``future`` with ``exc``; a bug (not a project error) is logged with its traceback."""
    if not isinstance(exc, SdfServerError):
        log.exception("engine command failed unexpectedly", exc_info=exc)
    if not future.done():
        future.set_exception(exc)


class BatchPipeline:
    def __init__(self, table: WorldTable, journal: Journal | None, metrics: EngineMetrics,
                 more_queued: Callable[[], bool]):
        self.table = table
        self.journal = journal
        self.metrics = metrics
        self.more_queued = more_queued
        self.acknowledging: list[list[tuple[Future, int]]] = []  # the step's applied batches
        self.remembered: dict[str, OrderedDict[str, int]] = {}  # world -> batch id -> version

    def remember(self, world_id: str, ids: list[tuple[str, int]]) -> None:
        """Record acknowledged (batch id, version) pairs of ``world_id`` (any thread)."""
        remembered = self.remembered.setdefault(world_id, OrderedDict())
        for batch_id, version in ids:
            remembered[batch_id] = version
        while len(remembered) > REMEMBERED_BATCHES:
            remembered.popitem(last=False)

    def forget_world(self, world_id: str) -> None:
        self.remembered.pop(world_id, None)

    def plan(self, command: ApplyEdits, future: Future, report: StepReport) -> Planned | None:
        started = time.perf_counter()
        try:
            if command.batch_id is not None:
                version = self.remembered.get(command.world_id, {}).get(command.batch_id)
                if version is not None:  # acknowledged before: the same answer, nothing applied
                    future.set_result(version)
                    return None
            return command, future, self.table.get(command.world_id).plan_edits(command.edits)
        except Exception as exc:
            self.reject(future, exc, report)
            return None
        finally:
            report.apply_ms["plan"] += (time.perf_counter() - started) * 1e3

    def run(self, batches: list[Planned], touched: set[str], report: StepReport) -> None:
        """Journal each world's planned batches in one record, apply them in order, acknowledge."""
        by_world: dict[str, list[Planned]] = {}
        for item in batches:
            by_world.setdefault(item[0].world_id, []).append(item)
        started = time.perf_counter()
        journaled = []
        for world_id, items in by_world.items():
            world = items[0][2].world
            durable = None
            if self.journal is not None:
                try:  # acknowledged once the journal has them on disk
                    durable = self.journal.record_batches(world_id, world.version + 1, [c.wire for c, _, _ in items])
                except Exception as exc:  # not journaled: not applied, not acknowledged
                    for _, future, _ in items:
                        self.reject(future, exc, report)
                    continue
            journaled.append((world_id, world, items, durable))
        if self.journal is not None and journaled:
            # every world's records in one round of syncs; with more commands queued the engine
            # does not wait for the committer to take them: under load that wait held up every step
            self.journal.start_syncs(wait=not self.more_queued())
        logged = time.perf_counter()
        report.apply_ms["log"] += (logged - started) * 1e3
        launch_ms, applied, pooled = 0.0, [], []
        try:
            for world_id, world, items, durable in journaled:
                if durable is not None and durable.done() and durable.exception() is not None:
                    for _, future, _ in items:  # its log record failed before it was applied
                        self.reject(future, durable.exception(), report)
                    continue
                launch = time.perf_counter()
                try:  # the step's brushes in few launches; pooled worlds' last ones after the loop
                    versions = world.apply_plans([plan for _, _, plan in items], pooled)
                except cl.Error:
                    raise
                except Exception as exc:  # logged but not applied: not acknowledged, the other worlds go on
                    for _, future, _ in items:
                        self.reject(future, exc, report)
                    continue
                finally:
                    launch_ms += (time.perf_counter() - launch) * 1e3
                applied.append((world_id, items, versions, durable))
            launch = time.perf_counter()
            enqueue_pooled_brushes(self.table.gpu, pooled)  # one launch per slot pool
            launch_ms += (time.perf_counter() - launch) * 1e3
        finally:  # what was applied is acknowledged, even when the device failed on a later world
            self._acknowledge(applied, touched, report)
        report.apply_ms["launch"] += launch_ms
        report.apply_ms["acknowledge"] += (time.perf_counter() - logged) * 1e3 - launch_ms

    def _acknowledge(self, applied: list, touched: set[str], report: StepReport) -> None:
        """Count the applied batches (before any is acknowledged; each inc takes a lock: once a
        step, not once a world), then answer each with its version, or once durable: the worlds
        whose records share one durable record (the step log's) with one callback for all."""
        if applied:
            self.metrics.edit_batches.inc(sum(len(items) for _, items, _, _ in applied))
            self.metrics.edit_ops.inc(sum(len(command.edits) for _, items, _, _ in applied for command, _, _ in items))
        waiting: dict[int, tuple[Any, list]] = {}  # id(shared durable) -> (it, its worlds' answers)
        for world_id, items, versions, durable in applied:
            report.applied_batches += len(items)
            answers = [(future, version) for (_, future, _), version in zip(items, versions)]
            self.acknowledging.append(answers)
            ids = [(command.batch_id, version) for (command, _, _), version in zip(items, versions)
                   if command.batch_id is not None]
            if durable is None:
                self.remember(world_id, ids)
                for future, version in answers:
                    future.set_result(version)
            else:  # remembered only once durable: a repeat must not be answered before that
                shared = getattr(durable, "shared", durable)
                waiting.setdefault(id(shared), (shared, []))[1].append((world_id, answers, ids, durable))
            touched.add(world_id)
        for shared, worlds in waiting.values():
            shared.add_done_callback(lambda done, worlds=worlds: self._durable(done, worlds))

    def _durable(self, done: Future, worlds: list) -> None:
        """``done`` (the durable record of ``worlds``' batches) completed: remember each world's
        batch ids and complete its answers with their versions, or fail them with the record's
        error or the world's own (``fence``: another engine took it over)."""
        error = done.exception()
        for world_id, answers, ids, durable in worlds:
            exc = error
            if exc is None and hasattr(durable, "fence"):  # a WorldDurable; a world log's own future
                exc = durable.fence()                         # has its fence in its exception already
            if exc is None and ids:
                try:
                    self.remember(world_id, ids)
                except Exception:  # the answers go out regardless
                    log.exception("remembering acknowledged batch ids failed")
            for future, version in answers:
                try:  # one failing must not keep the others unanswered
                    if exc is not None:
                        future.set_exception(exc)
                    else:
                        future.set_result(version)
                except Exception:
                    log.exception("acknowledging an edit batch failed")

    def reject(self, future: Future, exc: BaseException, report: StepReport) -> None:
        report.rejected_batches += 1
        self.metrics.rejected_batches.inc()
        fail(future, exc)

