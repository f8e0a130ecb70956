"""The engine: one thread owns the GpuContext and every World.

Request handlers never touch the device. They ``submit`` a command (see
``commands.py``) and await its future; the engine thread runs ``step()``
whenever commands are queued:

1. take every queued command;
2. apply: create, delete and reconfigure worlds and apply edit batches, in
   arrival order — each batch validated on its own, so a bad batch fails alone
   and changes nothing; a world's valid batches are journaled in one log write,
   applied in order and acknowledged with their versions (after the log sync);
   with no other command queued, the step waits for that acknowledgement;
3. recompute each touched world once, however many batches it took; a long recompute runs in
   pieces over several steps (6.), the world's own commands waiting for its end
   (``long_recomputes.py``) while other worlds are served;
4. publish the chunks each recompute rewrote to the subscribers of those chunks;
5. serve reads, point queries, frames, picks, subscriptions and ``run_on_device`` calls
   (one handler per command type), which therefore see every edit applied before them. A read whose ``min_version``
   the field has not reached waits for later steps until its deadline;
6. after the answers are out, run the long recomputes for up to ``limits.step_budget_ms``, in
   pieces of a quarter of that, stopping after a piece as soon as a command is queued.

The engine is handed its collaborators and only sequences them: the world table
(``worlds.py``), the batch pipeline (``batches.py``: plan -> journal -> apply -> acknowledge),
the reads and their waits (``reads.py``, one handler per command type) and the subscriptions
(``subscriptions.py``).

A command's own error fails that command alone. An error the step raises outside
any one command fails the step's commands with 500, and the engine goes on; an
OpenCL error from the device fails them with NotReady and marks the engine not
ready for good (``/readyz`` answers 503 with the cause). The thread itself, its
warm-up and its failures: ``lifetime.py``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import time
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Callable, ContextManager, TypeVar

import numpy as np
import pyopencl as cl

from sdfserver.engine.batches import BatchPipeline, Planned, fail
from sdfserver.engine.commands import (
    APPLY, AdoptWorld, ApplyEdits, CommandCalls, CreateWorld, DeleteWorld, Describe, EngineLimits, OnDevice,
    Reconfigure, ReleaseWorld, StepReport, Subscribe,
)
from sdfserver.engine.journal import Journal
from sdfserver.engine.lifetime import EngineLifetime, Pending
from sdfserver.engine.long_recomputes import LongRecomputes
from sdfserver.engine.mailbox import Subscription
from sdfserver.engine.metrics import EngineMetrics
from sdfserver.engine.moves import Moves
from sdfserver.engine.reads import Reads
from sdfserver.engine.stepclock import StepClock
from sdfserver.engine.subscriptions import Subscriptions
from sdfserver.engine.tickets import OnDone, Ticket
from sdfserver.engine.worlds import WorldTable, new_world_id, world_config_dict
from sdfserver.errors import DeviceMemoryExceeded, NotReady
from sdfserver.gpu import GpuContext
from sdfserver.stacked import begin_stacked
from sdfserver.world import RecomputeResult, World, WorldConfig

log = logging.getLogger("sdfserver.engine")
T = TypeVar("T")
DIRTY_GAUGE_EVERY_S = 0.1  # the dirty-chunks gauge is counted at most this often
# With nothing else queued, a step waits this long at most for its batches' acknowledgements
# before it recomputes (journal.wait_durable): the log's committer then acknowledges them without
# waiting for the GIL that the recompute would hold. It looks for newly queued commands every
# slice, so that a slow disk holds them up no longer than that.
LONE_ACKNOWLEDGEMENT_WAIT_S = 0.002
LONE_ACKNOWLEDGEMENT_SLICE_S = 0.00025
# A recompute in pieces is cut this many times finer than a step's budget for it: a command that
# comes while it runs waits for the piece on the device, not for the budget.
PIECES_PER_BUDGET = 4

__all__ = ["Engine", "EngineParts", "new_world_id", "world_config_dict"]


class _WorldsOf:
    """The world ids of a step's commands, found only when asked (only a busy step is asked)."""

    def __init__(self, commands: list[Pending]):
        self.commands = commands

    def __iter__(self):
        return (w for c, _ in self.commands if isinstance(w := getattr(c, "world_id", None), str))


@dataclass(frozen=True)
class EngineParts:
    """The engine's collaborators: what it sequences in a step."""

    table: WorldTable
    batches: BatchPipeline
    reads: Reads
    subscriptions: Subscriptions

    @classmethod
    def build(cls, gpu: GpuContext, limits: EngineLimits, journal: Journal | None, metrics: EngineMetrics,
              more_queued: Callable[[], bool]) -> "EngineParts":
        table = WorldTable(gpu, limits, journal, metrics)
        subscriptions = Subscriptions(table, limits.max_subscription_voxels, metrics)
        return cls(table, BatchPipeline(table, journal, metrics, more_queued),
                   Reads(gpu, table, subscriptions, limits), subscriptions)


class Engine(EngineLifetime, CommandCalls):
    def __init__(self, gpu: GpuContext, limits: EngineLimits = EngineLimits(), *,
                 journal: Journal | None = None, metrics: EngineMetrics | None = None,
                 parts: EngineParts | None = None):
        """``parts``: the collaborators, handed in; by default built from the other arguments."""
        super().__init__()
        self.gpu = gpu
        self.limits = limits
        self.journal = journal
        self.metrics = metrics or EngineMetrics()
        parts = parts or EngineParts.build(gpu, limits, journal, self.metrics, lambda: not self._commands.empty())
        self.table, self.batches, self.reads, self.subscriptions = (
            parts.table, parts.batches, parts.reads, parts.subscriptions)
        self.moves = Moves(gpu, limits, self.table, self.batches, self.subscriptions, journal)
        self.long = LongRecomputes()
        self._changers: dict[type, Callable[[Any, set[str]], Any]] = {  # the changing commands' handlers
            CreateWorld: self._create_world, DeleteWorld: self._delete_world, Reconfigure: self._reconfigure,
            ReleaseWorld: lambda c, _: self.moves.release(c.world_id, c.destination),
            AdoptWorld: lambda c, _: self.moves.adopt(c.world_id, c.source),
        }
        # the table's own dicts: read by restore, tests and the engine's service
        self.worlds, self.owners, self.refused = self.table.worlds, self.table.owners, self.table.refused
        self.last_recompute_ms = self.table.last_recompute_ms
        self._dirty_gauge_at = -DIRTY_GAUGE_EVERY_S
        self.metrics.queue_depth.set_function(self._commands.qsize)
        self.running: StepClock | None = None  # the step under way, if any
        self.metrics.busy_seconds.set_function(self._busy_seconds)
        # a step's answers are completed inside this: the engine process's transport sends them
        # together (EngineTransport.holding)
        self.answering: Callable[[], ContextManager[Any]] = contextlib.nullcontext

    # -- lifetime -----------------------------------------------------------------------------

    def _release_all(self) -> None:
        self.reads.release()
        self.table.release_all()

    # -- submitting (any thread) ----------------------------------------------------------------

    def submit(self, command: Any, on_done: OnDone | None = None) -> Future | Ticket:
        """Queue a command; its result arrives in the returned Future, or with ``on_done``
        given, in a call ``on_done(result, error)`` on the thread that completes it (a Ticket)."""
        future = Future() if on_done is None else Ticket(on_done)
        if self._refuse_if_failed(future):
            return future
        self._commands.put((command, future))
        if not self._wake.is_set():  # set() takes a lock; the engine clears the flag before it drains
            self._wake.set()
        if self.failure is not None or self._stopping:  # it failed or stopped meanwhile: drained here
            self._fail_all(NotReady(self.not_ready_reason()), self._drain())
        return future

    async def call(self, command: Any) -> Any:
        return await asyncio.wrap_future(self.submit(command))

    async def create_world(self, config: WorldConfig, world_id: str | None = None,
                           owner: str | None = None, voxels: np.ndarray | None = None) -> dict[str, Any]:
        return await self.call(CreateWorld(config, world_id, owner, voxels))

    async def delete_world(self, world_id: str) -> None:
        await self.call(DeleteWorld(world_id))

    async def reconfigure(self, world_id: str, **changes: Any) -> dict[str, Any]:
        return await self.call(Reconfigure(world_id, changes))

    async def describe(self, world_id: str) -> dict[str, Any]:
        return await self.call(Describe(world_id))

    async def list_worlds(self) -> list[dict[str, Any]]:
        return await self.call(Describe(None))

    async def subscribe(self, subscription: Subscription) -> None:
        await self.call(Subscribe(subscription))

    def unsubscribe(self, subscription: Subscription) -> None:
        self.subscriptions.unsubscribe(subscription)

    async def run_on_device(self, fn: Callable[[], T]) -> T:
        """Run ``fn()`` on the engine thread between steps (after that step's recompute)."""
        return await self.call(OnDevice(fn))

    @property
    def max_wait_s(self) -> float:
        return self.limits.max_wait_s

    # -- the step (engine thread) -----------------------------------------------------------------

    def step(self) -> StepReport:
        """Apply queued edits, recompute touched worlds once each, publish, serve reads."""
        commands = self.long.take_released() + self._drain()
        serve = self._waiting + [c for c in commands if not isinstance(c[0], APPLY)]
        self._waiting, self.batches.acknowledging = [], []
        report = StepReport()
        self.running = clock = StepClock(report)
        answers: list[tuple[Future, Any]] = []
        try:
            changing = [c for c in commands if isinstance(c[0], APPLY)]
            clock.doing("apply", _WorldsOf(changing))
            touched = self._apply(changing, report) | self.long.take_restoring()
            clock.lap("apply")
            if self.batches.acknowledging and self.journal is not None:
                clock.doing("durable")
                self._wait_for_acknowledgements()
                clock.lap("durable")
            clock.doing("recompute", touched)
            report.recomputed = self._recompute(touched)
            clock.lap("recompute")
            clock.doing("publish", report.recomputed)
            self.subscriptions.publish(report.recomputed)
            clock.lap("publish")
            clock.doing("serve", _WorldsOf(serve))
            serve = [c for c in serve if not self.long.hold(*c)]
            answers = self.reads.serve(serve, report, self._waiting)
            clock.lap("serve")
        except cl.Error as exc:
            self._lose_device(exc, self._unanswered(commands + serve + self._waiting) + self._held_all())
            self._waiting = []
        except Exception as exc:
            self._stop_long_recomputes()  # a piece that failed would fail again every step
            self._fail_step(exc, self._unanswered(commands + serve + self._waiting))
            self._waiting, answers = [], []
        with self.answering():  # before the step's bookkeeping: they need not wait for it
            for future, result in answers:
                future.set_result(result)
        if self.long.running:
            self._advance_long_recomputes(report, clock)
        self.subscriptions.count_pending()
        clock.stop(self.metrics, self.limits.slow_step_ms)
        self.running = None
        return report

    def busy(self) -> dict[str, Any] | None:
        """The running step's phase, worlds and time, when it has run ``limits.busy_step_ms`` or
        longer, and the recomputes running in pieces; else None (any thread: /readyz and
        /metrics ask while the step runs)."""
        clock = self.running
        step = None if clock is None else clock.busy(self.limits.busy_step_ms)
        long = self.long.describe()
        if not long:
            return step
        busy_ms = max(e["running_ms"] for e in long)
        step = step or {"busy_ms": busy_ms, "phase": "pieces", "worlds": sorted(e["world"] for e in long)}
        return {**step, "recomputing": long}

    def _busy_seconds(self) -> float:
        busy = self.busy()
        return 0.0 if busy is None else busy["busy_ms"] / 1e3

    def _stop_long_recomputes(self) -> None:
        """Give up the recomputes running in pieces; their worlds recompute whole at their next edit."""
        for world_id in self.long.give_up():
            world = self.worlds.get(world_id)
            if world is not None and world.config.storage == "dense":
                world.mark_all_dirty()

    def _wait_timeout(self) -> float | None:
        return 0.0 if self.long.has_work else super()._wait_timeout()

    def _held_all(self) -> list[Pending]:
        return self.long.all_waiting()

    def _wait_for_acknowledgements(self) -> None:
        """While no other command is queued, wait for this step's batches to be acknowledged."""
        deadline = time.monotonic() + LONE_ACKNOWLEDGEMENT_WAIT_S
        while self._commands.empty():
            left = deadline - time.monotonic()
            if left <= 0 or self.journal.wait_durable(min(left, LONE_ACKNOWLEDGEMENT_SLICE_S)):
                return

    def _unanswered(self, pending: list[Pending]) -> list[Pending]:
        """``pending`` less the batches applied this step: they are in the log and the world,
        and are answered by their acknowledgement."""
        applied = {id(future) for answers in self.batches.acknowledging for future, _ in answers}
        return [p for p in pending if id(p[1]) not in applied]

    def _drain(self) -> list[Pending]:
        out = []
        while True:
            try:
                out.append(self._commands.get_nowait())
            except queue.Empty:
                return out

    def _apply(self, commands: list[Pending], report: StepReport) -> set[str]:
        """Run the changing commands in arrival order. Edit batches are planned one by one as
        they come and journaled and applied together (one log write per world) before the next
        command of another kind, so that command still sees them."""
        touched: set[str] = set()
        batches: list[Planned] = []
        for command, future in commands:
            if self.long.hold(command, future):  # after its world's recompute in pieces
                continue
            if not future.set_running_or_notify_cancel():
                continue
            if isinstance(command, ApplyEdits):
                self.moves.drop_if_fenced(command.world_id)
                planned = self.batches.plan(command, future, report)  # a bad batch fails alone
                if planned is not None:
                    batches.append(planned)
                continue
            self.batches.run(batches, touched, report)
            batches = []
            try:
                result = self._changers[type(command)](command, touched)
            except cl.Error:
                raise
            except Exception as exc:  # the command fails alone; the engine carries on
                fail(future, exc)
            else:
                future.set_result(result)
        self.batches.run(batches, touched, report)
        return touched

    def _create_world(self, command: CreateWorld, touched: set[str]) -> dict[str, Any]:
        world_id = self.table.create(command)
        if command.voxels is not None:
            touched.add(world_id)  # an import: compute its field this step
        return self.table.describe(world_id)

    def _delete_world(self, command: DeleteWorld, touched: set[str]) -> None:
        self.long.cancel(command.world_id)
        self.table.delete(command.world_id)
        self.subscriptions.drop_world(command.world_id)
        self.batches.forget_world(command.world_id)

    def _reconfigure(self, command: Reconfigure, touched: set[str]) -> None:
        self.table.reconfigure(command.world_id, command.changes)
        touched.add(command.world_id)

    def _recompute(self, touched: set[str]) -> dict[str, RecomputeResult]:
        """One recompute per touched world (the step's one loop over worlds), and the step's share
        of those running in pieces."""
        worlds = {i: self.worlds[i] for i in touched if i in self.worlds}
        now = time.monotonic()
        if now - self._dirty_gauge_at >= DIRTY_GAUGE_EVERY_S:  # counting costs more than the gauge is worth each step
            self._dirty_gauge_at = now
            self.metrics.dirty_chunks.set(sum(w.dirty_chunk_count for w in worlds.values()))
        # Every world's work goes to the device before the step waits, once, for all of it: a
        # wait per world would leave the device idle while the next world's launches are made.
        piece_s = self.limits.step_budget_ms / 1e3 / PIECES_PER_BUDGET
        pending = begin_stacked(self.gpu, worlds)  # pooled worlds side by side: one run per pool
        pending.update((world_id, world.begin_recompute(piece_s)) for world_id, world in worlds.items()
                       if world_id not in pending)
        for world_id, started in list(pending.items()):
            if started.in_pieces:
                self.long.start(world_id, pending.pop(world_id), worlds[world_id].config.algorithm)
        if len(pending) > 1:
            self.gpu.queue.finish()
        return self._finished([(world_id, p.finish(device_done=len(pending) > 1)) for world_id, p in pending.items()])

    def _advance_long_recomputes(self, report: StepReport, clock: StepClock) -> None:
        """The step's share of the recomputes running in pieces, after its answers are out; those
        that end are published now, and the commands that waited for them run next step."""
        clock.doing("pieces", list(self.long.running))
        try:
            done = self.long.advance(self.limits.step_budget_ms / 1e3, lambda: not self._commands.empty())
            results = self._finished([(world_id, p.finish(device_done=True)) for world_id, p in done.items()])
            self.subscriptions.publish(results)
            report.recomputed.update(results)
        except cl.Error as exc:
            self._lose_device(exc, self._held_all())
        except Exception as exc:
            self._stop_long_recomputes()
            self._fail_step(exc, self._held_all())
        clock.lap("pieces")

    def _finished(self, finished: list[tuple[str, RecomputeResult]]) -> dict[str, RecomputeResult]:
        """Count the recomputes that ended and snapshot their worlds where due."""
        observed, results = [], {}
        for world_id, result in finished:
            world = self.worlds[world_id]
            observed.append((world.config.algorithm, result))
            self.last_recompute_ms[world_id] = result.wall_ms
            results[world_id] = result
            if self.journal is not None and self.journal.wants_snapshot(world_id):
                self._snapshot(world_id, world)
        self.metrics.observe_recomputes(observed)  # the step's figures counted once
        return results

    def _snapshot(self, world_id: str, world: World) -> None:
        try:
            voxels, ready = world.copy_voxels_out()  # the journal's thread waits for it, not this one
        except DeviceMemoryExceeded as exc:  # no room to stage the copy; the log still has every batch
            log.warning("snapshot of world %s skipped: %s", world_id, exc)
            return
        self.journal.record_snapshot(world_id, world.version, world_config_dict(world.config), voxels, ready)

    # -- the table, for start-up and the service ----------------------------------------------------

    def adopt_world(self, world_id: str, world: World, owner: str | None, field_pending: bool = False) -> None:
        """Register a world restored from disk; only before ``start()``. ``field_pending``: its
        field is still to be computed, by the first step (which serves its reads after that)."""
        if self.started:
            raise RuntimeError("adopt_world is for start-up, before the engine thread runs")
        self.table.adopt(world_id, world, owner)
        if field_pending:
            self.long.restore(world_id)

    def owner_of(self, world_id: str) -> str | None:
        """The owning key's name (any thread); NotFound for an unknown world."""
        return self.table.owner_of(world_id)
