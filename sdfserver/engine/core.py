"""The engine: one thread owns the GpuContext and every World.

Request handlers never touch the device. They ``submit`` a command (see
``commands.py``) and await its future; the engine thread runs ``step()``
whenever commands are queued:

1. take every queued command;
2. apply: create, delete and reconfigure worlds and apply edit batches, in
   arrival order — each batch validated on its own, so a bad batch fails alone
   and changes nothing; a world's valid batches are journaled in one log write,
   applied in order and acknowledged with their versions (after the log sync);
3. recompute each touched world once, however many batches it took;
4. publish the chunks each recompute rewrote to the subscribers of those chunks;
5. serve reads, point queries, subscriptions and ``run_on_device`` calls, which
   therefore see every edit applied before them. A read whose ``min_version``
   the field has not reached waits for later steps until its deadline.

A command's own error fails that command alone. An error the step raises outside
any one command fails the step's commands with 500, and the engine goes on; an
OpenCL error from the device fails them with NotReady and marks the engine not
ready for good (``/readyz`` answers 503 with the cause). The thread itself, its
warm-up and its failures: ``lifetime.py``.
"""

from __future__ import annotations

import asyncio
import logging
import queue
import secrets
import threading
import time
from concurrent.futures import Future
from dataclasses import asdict
from typing import Any, Callable, TypeVar

import numpy as np
import pyopencl as cl

from sdfserver.delivery import delivery_round
from sdfserver.engine.commands import (
    APPLY, ApplyEdits, CommandCalls, Completion, CreateWorld, DeleteWorld, Describe, EngineLimits, OnDevice, Query,
    Read, ReadResult, Reconfigure, StepReport, Subscribe,
)
from sdfserver.engine.describe import describe_recompute
from sdfserver.engine.journal import Journal, reconfigure_durably
from sdfserver.engine.lifetime import EngineLifetime, Pending
from sdfserver.engine.mailbox import Subscription
from sdfserver.engine.metrics import EngineMetrics
from sdfserver.engine.publish import check_subscription_region, chunks_of, publish
from sdfserver.engine.query import query_points
from sdfserver.engine.stepclock import StepClock
from sdfserver.errors import (
    DeviceMemoryExceeded, InvalidInput, NotFound, NotReady, SdfServerError, StorageError, TooLarge,
    VersionNotReached,
)
from sdfserver.gpu import GpuContext
from sdfserver.world import EditPlan, RecomputeResult, World, WorldConfig

log = logging.getLogger("sdfserver.engine")
T = TypeVar("T")
DIRTY_GAUGE_EVERY_S = 0.1  # the dirty-chunks gauge is counted at most this often


def world_config_dict(config: WorldConfig) -> dict[str, Any]:
    """A WorldConfig in wire form (the body of ``POST /v1/worlds``)."""
    d = asdict(config)
    d["size"] = list(config.size)
    if config.focus is not None:
        d["focus"] = {"center": list(config.focus.center), "size": list(config.focus.size)}
    return d


def new_world_id() -> str:
    # Hex, not url-safe base64: an id that starts with '-' reads as an option on command lines.
    return secrets.token_hex(6)


class Engine(EngineLifetime, CommandCalls):
    def __init__(self, gpu: GpuContext, limits: EngineLimits = EngineLimits(), *,
                 journal: Journal | None = None, metrics: EngineMetrics | None = None):
        super().__init__()
        self.gpu = gpu
        self.limits = limits
        self.journal = journal
        self.metrics = metrics or EngineMetrics()
        self.worlds: dict[str, World] = {}  # engine thread only
        self.owners: dict[str, str | None] = {}  # written by the engine thread, read by any
        self.refused: dict[str, str] = {}  # worlds on disk that could not be restored, and why
        self.last_recompute_ms: dict[str, float] = {}
        self._subscribers: dict[str, set[Subscription]] = {}
        self._subscribers_lock = threading.Lock()
        self._acknowledging: list[list[tuple[Future, int]]] = []  # the step's applied batches
        self._dirty_gauge_at = -DIRTY_GAUGE_EVERY_S
        self.metrics.queue_depth.set_function(self._commands.qsize)

    # -- lifetime -----------------------------------------------------------------------------

    def _release_all(self) -> None:
        for world in self.worlds.values():
            world.release()
        self.worlds.clear()

    # -- submitting (any thread) ----------------------------------------------------------------

    def submit(self, command: Any, completion: Completion | None = None) -> Future | Completion:
        """Queue a command; its result arrives in the returned Future, or through ``completion``."""
        future = Future() if completion is None else completion
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
        with self._subscribers_lock:
            subs = self._subscribers.get(subscription.world_id)
            if subs is not None:
                subs.discard(subscription)
        self._count_subscribers()
        self._count_pending()  # what its mailbox held leaves the gauges now, not at the next step

    async def run_on_device(self, fn: Callable[[], T]) -> T:
        """Run ``fn()`` on the engine thread between steps (after that step's recompute)."""
        return await self.call(OnDevice(fn))

    @property
    def max_wait_s(self) -> float:
        return self.limits.max_wait_s

    # -- the step (engine thread) -----------------------------------------------------------------

    def step(self) -> StepReport:
        """Apply queued edits, recompute touched worlds once each, publish, serve reads."""
        with delivery_round():  # what the step answers, a receiver may send together at its end
            return self._step()

    def _step(self) -> StepReport:
        commands = self._drain()
        serve = self._waiting + [c for c in commands if not isinstance(c[0], APPLY)]
        self._waiting, self._acknowledging = [], []
        report = StepReport()
        clock = StepClock(report)
        answers: list[tuple[Future, Any]] = []
        try:
            touched = self._apply([c for c in commands if isinstance(c[0], APPLY)], report)
            clock.lap("apply")
            report.recomputed = self._recompute(touched)
            clock.lap("recompute")
            self._publish(report.recomputed)
            clock.lap("publish")
            answers = self._serve(serve, report)
            clock.lap("serve")
        except cl.Error as exc:
            self._lose_device(exc, self._unanswered(commands + serve + self._waiting))
            self._waiting = []
        except Exception as exc:
            self._fail_step(exc, self._unanswered(commands + serve + self._waiting))
            self._waiting, answers = [], []
        self._count_pending()
        clock.stop(self.metrics, self.limits.slow_step_ms)
        for future, result in answers:  # last: a receiver may need the GIL this thread holds
            future.set_result(result)
        return report

    def _unanswered(self, pending: list[Pending]) -> list[Pending]:
        """``pending`` less the batches applied this step: they are in the log and the world,
        and are answered by their acknowledgement."""
        applied = {id(future) for answers in self._acknowledging for future, _ in answers}
        return [p for p in pending if id(p[1]) not in applied]

    def _drain(self) -> list[Pending]:
        out = []
        while True:
            try:
                out.append(self._commands.get_nowait())
            except queue.Empty:
                return out

    def _apply(self, commands: list[Pending], report: StepReport) -> set[str]:
        """Run the changing commands in arrival order. Edit batches are validated one by one as
        they come and journaled and applied together (one log write per world) before the next
        command of another kind, so that command still sees them."""
        touched: set[str] = set()
        batches: list[tuple[ApplyEdits, Future, EditPlan]] = []
        for command, future in commands:
            if not future.set_running_or_notify_cancel():
                continue
            if isinstance(command, ApplyEdits):
                started = time.perf_counter()
                try:  # a bad batch fails alone: nothing logged or applied
                    batches.append((command, future, self._world(command.world_id).plan_edits(command.edits)))
                except Exception as exc:
                    self._reject(future, exc, report)
                report.apply_ms["plan"] += (time.perf_counter() - started) * 1e3
                continue
            self._apply_batches(batches, touched, report)
            batches = []
            try:
                if isinstance(command, CreateWorld):
                    result = self._create_world(command)
                    if command.voxels is not None:
                        touched.add(result["id"])  # an import: compute its field this step
                elif isinstance(command, DeleteWorld):
                    result = self._delete_world(command.world_id)
                else:
                    reconfigure_durably(self.journal, command.world_id, self._world(command.world_id),
                                        command.changes, world_config_dict)
                    touched.add(command.world_id)
                    result = None
            except cl.Error:
                raise
            except Exception as exc:  # the command fails alone; the engine carries on
                self._fail(future, exc)
            else:
                future.set_result(result)
        self._apply_batches(batches, touched, report)
        return touched

    def _apply_batches(self, batches: list[tuple[ApplyEdits, Future, EditPlan]], touched: set[str],
                       report: StepReport) -> None:
        """Journal each world's validated batches in one record, apply them in order, acknowledge."""
        by_world: dict[str, list[tuple[ApplyEdits, Future, EditPlan]]] = {}
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
                        self._reject(future, exc, report)
                    continue
            journaled.append((world_id, world, items, durable))
        if self.journal is not None and journaled:
            # every world's records in one round of syncs; with more commands queued the engine
            # does not wait for the committer to take them: under load that wait held up every step
            self.journal.start_syncs(wait=self._commands.empty())
        logged = time.perf_counter()
        report.apply_ms["log"] += (logged - started) * 1e3
        launch_ms = 0.0
        for world_id, world, items, durable in journaled:
            launch = time.perf_counter()
            try:
                versions = world.apply_plans([plan for _, _, plan in items])  # the step's brushes in few launches
            except cl.Error:
                raise
            except Exception as exc:  # logged but not applied: not acknowledged, the other worlds go on
                for _, future, _ in items:
                    self._reject(future, exc, report)
                continue
            finally:
                launch_ms += (time.perf_counter() - launch) * 1e3
            self.metrics.edit_batches.inc(len(items))  # each inc takes a lock: once a world a step
            self.metrics.edit_ops.inc(sum(len(command.edits) for command, _, _ in items))
            report.applied_batches += len(items)
            answers = [(future, version) for (_, future, _), version in zip(items, versions)]
            self._acknowledging.append(answers)
            if durable is None:
                for future, version in answers:
                    future.set_result(version)
            else:
                _acknowledge_when_durable(answers, durable)
            touched.add(world_id)
        report.apply_ms["launch"] += launch_ms
        report.apply_ms["acknowledge"] += (time.perf_counter() - logged) * 1e3 - launch_ms

    def _reject(self, future: Future, exc: BaseException, report: StepReport) -> None:
        report.rejected_batches += 1
        self.metrics.rejected_batches.inc()
        self._fail(future, exc)

    def _create_world(self, command: CreateWorld) -> dict[str, Any]:
        config = command.config.validated()
        sx, sy, sz = config.size
        if sx * sy * sz > self.limits.max_world_voxels:
            raise TooLarge(f"a {sx}x{sy}x{sz} world has {sx * sy * sz} voxels; the limit is "
                           f"{self.limits.max_world_voxels}")
        if len(self.worlds) >= self.limits.max_worlds:
            raise TooLarge(f"the server already holds {len(self.worlds)} worlds, its limit")
        world_id = command.world_id or new_world_id()
        while world_id in self.worlds:
            if command.world_id:
                raise InvalidInput(f"world {world_id!r} already exists")
            world_id = new_world_id()
        world = World(self.gpu, config, self.limits.edits)
        try:
            if command.voxels is not None:
                world.load_voxels(command.voxels)
            if self.journal is not None and command.voxels is None:
                self.journal.record_create(world_id, world_config_dict(world.config), command.owner)
            elif self.journal is not None:
                self.journal.record_create(world_id, world_config_dict(world.config), command.owner,
                                           voxels=command.voxels, version=world.version)
        except BaseException:
            world.release()
            raise
        self.worlds[world_id] = world
        self.owners[world_id] = command.owner
        self._count_worlds()
        return self._describe(world_id)

    def _delete_world(self, world_id: str) -> None:
        world = self._world(world_id)
        if self.journal is not None:
            self.journal.record_delete(world_id)
        del self.worlds[world_id]
        self.owners.pop(world_id, None)
        self.last_recompute_ms.pop(world_id, None)
        world.release()
        with self._subscribers_lock:
            self._subscribers.pop(world_id, None)
        self._count_worlds()

    def _recompute(self, touched: set[str]) -> dict[str, RecomputeResult]:
        results = {}
        worlds = {i: self.worlds[i] for i in touched if i in self.worlds}
        now = time.monotonic()
        if now - self._dirty_gauge_at >= DIRTY_GAUGE_EVERY_S:  # counting costs more than the gauge is worth each step
            self._dirty_gauge_at = now
            self.metrics.dirty_chunks.set(sum(w.dirty_chunk_count for w in worlds.values()))
        for world_id, world in worlds.items():
            result = world.recompute()
            self.metrics.observe_recompute(world.config.algorithm, result)
            self.last_recompute_ms[world_id] = result.wall_ms
            results[world_id] = result
            if self.journal is not None and self.journal.wants_snapshot(world_id):
                self._snapshot(world_id, world)
        return results

    def _snapshot(self, world_id: str, world: World) -> None:
        try:
            voxels, ready = world.copy_voxels_out()  # the journal's thread waits for it, not this one
        except DeviceMemoryExceeded as exc:  # no room to stage the copy; the log still has every batch
            log.warning("snapshot of world %s skipped: %s", world_id, exc)
            return
        self.journal.record_snapshot(world_id, world.version, world_config_dict(world.config), voxels, ready)

    # -- publishing ---------------------------------------------------------------------------------

    def _publish(self, recomputed: dict[str, RecomputeResult]) -> None:
        for world_id, result in recomputed.items():
            with self._subscribers_lock:
                subs = list(self._subscribers.get(world_id, ()))
            if subs:
                self.metrics.merged_chunks.inc(publish(self.worlds[world_id], result, subs))

    def _subscribe(self, sub: Subscription) -> None:
        world = self._world(sub.world_id)
        region = sub.region
        check_subscription_region(region, world.world_box, self.limits.max_subscription_voxels)
        # The current state first, then every change: the subscriber never misses one.
        field = world.read_field(region)
        sub.mailbox.put(world.field_version, chunks_of(field, region.lo, region, world.config.chunk_size,
                                                        sub.format))
        with self._subscribers_lock:
            self._subscribers.setdefault(sub.world_id, set()).add(sub)
        self._count_subscribers()

    # -- serving -------------------------------------------------------------------------------------

    def _serve(self, commands: list[Pending], report: StepReport) -> list[tuple[Future, Any]]:
        """Run the serving commands; returns the answers for the caller to deliver."""
        now = time.monotonic()
        answers = []
        for command, future in commands:
            if future.cancelled():
                continue
            try:
                if isinstance(command, (Read, Query)) and self._must_wait(command, now):
                    self._waiting.append((command, future))
                    continue
                if not future.set_running_or_notify_cancel():
                    continue
                result = self._serve_one(command)
            except cl.Error:
                raise
            except Exception as exc:
                self._fail(future, exc)
            else:
                answers.append((future, result))
                report.served += 1
        report.waiting = len(self._waiting)
        return answers

    def _must_wait(self, command: Read | Query, now: float) -> bool:
        world = self._world(command.world_id)
        have = world.version if isinstance(command, Read) and command.kind == "voxels" else world.field_version
        if have >= command.min_version:
            return False
        if now < command.deadline:
            return True
        raise VersionNotReached(f"world {command.world_id!r} is at version {have}; min_version "
                                f"{command.min_version} was not reached in {self.limits.max_wait_s:g} s")

    def _serve_one(self, command: Any) -> Any:
        if isinstance(command, Read):
            return self._read(command)
        if isinstance(command, Query):
            return query_points(self._world(command.world_id), command.points)
        if isinstance(command, Describe):
            if command.world_id is None:
                return [self._describe(i) for i in sorted(self.worlds)]
            return self._describe(command.world_id)
        if isinstance(command, Subscribe):
            return self._subscribe(command.subscription)
        if isinstance(command, OnDevice):
            return command.fn()
        raise TypeError(f"not an engine command: {command!r}")

    def _read(self, command: Read) -> ReadResult:
        world = self._world(command.world_id)
        box = world.world_box if command.box is None else command.box
        if box.volume > self.limits.max_read_voxels:
            raise TooLarge(f"a read of {box.volume} voxels; the limit is {self.limits.max_read_voxels}")
        if command.kind == "voxels":
            return ReadResult(box.lo, world.version, world.read_voxels(box))
        array = world.read_distance(box) if command.kind == "distance" else world.read_field(box)
        return ReadResult(box.lo, world.field_version, array)

    def _describe(self, world_id: str) -> dict[str, Any]:
        world = self._world(world_id)
        return {
            "id": world_id,
            **world_config_dict(world.config),
            "version": world.version,
            "field_version": world.field_version,
            "dirty_chunks": world.dirty_chunk_count,
            "last_recompute_ms": self.last_recompute_ms.get(world_id),
            "last_recompute": describe_recompute(world.last_recompute),
            "device_bytes": world.device_bytes,
            "owner": self.owners.get(world_id),
        }

    def _world(self, world_id: str) -> World:
        try:
            return self.worlds[world_id]
        except (KeyError, TypeError):
            if isinstance(world_id, str) and world_id in self.refused:
                raise StorageError(f"world {world_id!r} was not restored: {self.refused[world_id]}") from None
            raise NotFound(f"no world {world_id!r}") from None

    def adopt_world(self, world_id: str, world: World, owner: str | None) -> None:
        """Register a world restored from disk; only before ``start()``."""
        if self.started:
            raise RuntimeError("adopt_world is for start-up, before the engine thread runs")
        self.worlds[world_id] = world
        self.owners[world_id] = owner
        self._count_worlds()

    def owner_of(self, world_id: str) -> str | None:
        """The owning key's name (any thread); NotFound for an unknown world."""
        try:
            return self.owners[world_id]
        except KeyError:
            self._world(world_id)
            raise NotFound(f"no world {world_id!r}") from None

    # -- failures and gauges -----------------------------------------------------------------------

    def _fail(self, future: Future, exc: BaseException) -> None:
        if not isinstance(exc, SdfServerError):
            log.exception("engine command failed unexpectedly", exc_info=exc)
        if not future.done():
            future.set_exception(exc)

    def _count_worlds(self) -> None:
        self.metrics.worlds.set(len(self.worlds))
        self.metrics.device_bytes.set(sum(w.device_bytes for w in self.worlds.values()))

    def _count_subscribers(self) -> None:
        with self._subscribers_lock:
            self.metrics.subscribers.set(sum(len(s) for s in self._subscribers.values()))

    def _count_pending(self) -> None:
        with self._subscribers_lock:
            subs = [s for group in self._subscribers.values() for s in group]
        self.metrics.pending_chunks.set(sum(s.mailbox.pending_chunks for s in subs))
        self.metrics.pending_bytes.set(sum(s.mailbox.pending_bytes for s in subs))


def _acknowledge_when_durable(answers: list[tuple[Future, int]], durable: Future) -> None:
    """Complete each future with its version once ``durable`` completes (or fail them all with
    its error): one callback for a world's batches of a step, not one each."""

    def done(durable: Future) -> None:
        exc = durable.exception()
        for future, version in answers:
            try:  # one failing must not keep the others unanswered
                if exc is not None:
                    future.set_exception(exc)
                else:
                    future.set_result(version)
            except Exception:
                log.exception("acknowledging an edit batch failed")

    durable.add_done_callback(done)
