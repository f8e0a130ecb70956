"""What a step serves after its recompute, one handler per command type: field and voxel reads,
point queries, descriptions, subscriptions, frames, picks and a sparse world's bricks (exports). A read or query whose
``min_version`` the world has not reached waits for later steps until its deadline."""

from __future__ import annotations

import time
from concurrent.futures import Future
from typing import Any, Callable

import pyopencl as cl

from sdfserver.engine.batches import fail
from sdfserver.engine.commands import (
    CopyBricks, Describe, Draw, EngineLimits, OnDevice, PickAt, Query, Read, ReadResult, StepReport, Subscribe,
)
from sdfserver.engine.query import run_query
from sdfserver.engine.subscriptions import Subscriptions
from sdfserver.engine.worlds import WorldTable, world_config_dict
from sdfserver.field_values import packed_content
from sdfserver.errors import InvalidInput, TooLarge, VersionNotReached
from sdfserver.gpu import GpuContext
from sdfserver.render import Renderer

Pending = tuple[Any, Future]


class Reads:
    def __init__(self, gpu: GpuContext, table: WorldTable, subscriptions: Subscriptions, limits: EngineLimits):
        self.gpu = gpu
        self.table = table
        self.limits = limits
        self._renderer: Renderer | None = None
        self.handlers: dict[type, Callable[[Any], Any]] = {
            Read: self.read,
            Query: lambda c: run_query(table.get(c.world_id), c.kind, c.rows),
            Describe: lambda c: table.describe(c.world_id),
            Subscribe: lambda c: subscriptions.subscribe(c.subscription),
            Draw: self.draw,
            PickAt: self.pick,
            OnDevice: lambda c: c.fn(),
            CopyBricks: self.copy_bricks,
        }

    def copy_bricks(self, command: CopyBricks) -> tuple[int, dict[str, Any], Any, Callable[[], None]]:
        world = self.table.get(command.world_id)
        if world.config.storage != "sparse":
            raise InvalidInput("only a sparse world's bricks are copied; a dense world exports its voxels")
        stored = world.stored_bricks * world.brick ** 3
        if stored > self.limits.max_read_voxels:
            raise TooLarge(f"world {command.world_id!r} stores {stored} voxels; an export holds at most "
                           f"{self.limits.max_read_voxels} (max_read_voxels)")
        content, wait = world.copy_voxels_out()
        return world.version, world_config_dict(world.config), content, wait

    def serve(self, commands: list[Pending], report: StepReport, waiting: list[Pending]) -> list[tuple[Future, Any]]:
        """Run the serving commands; returns the answers for the caller to deliver. A read or
        query whose version is not there yet goes to ``waiting``."""
        now = time.monotonic()
        answers = []
        for command, future in commands:
            if future.cancelled():
                continue
            try:
                if isinstance(command, (Read, Query)) and self._must_wait(command, now):
                    waiting.append((command, future))
                    continue
                if not future.set_running_or_notify_cancel():
                    continue
                handler = self.handlers.get(type(command))
                if handler is None:
                    raise TypeError(f"not an engine command: {command!r}")
                result = handler(command)
            except cl.Error:
                raise
            except Exception as exc:
                fail(future, exc)
            else:
                answers.append((future, result))
                report.served += 1
        report.waiting = len(waiting)
        return answers

    def _must_wait(self, command: Read | Query, now: float) -> bool:
        world = self.table.get(command.world_id)
        have = world.version if isinstance(command, Read) and command.kind == "voxels" else world.field_version
        if have >= command.min_version:
            return False
        if now < command.deadline:
            return True
        raise VersionNotReached(f"world {command.world_id!r} is at version {have}; min_version "
                                f"{command.min_version} was not reached in {self.limits.max_wait_s:g} s")

    def read(self, command: Read) -> ReadResult:
        world = self.table.get(command.world_id)
        box = world.world_box if command.box is None else command.box
        if box.volume > self.limits.max_read_voxels:
            raise TooLarge(f"a read of {box.volume} voxels; the limit is {self.limits.max_read_voxels}")
        if command.kind == "voxels":
            return ReadResult(box.lo, world.version, world.read_voxels(box), "voxels")
        if command.kind == "distance":
            return ReadResult(box.lo, world.field_version, world.read_distance(box), "distance")
        return ReadResult(box.lo, world.field_version, world.read_field(box), packed_content(world.config))

    def draw(self, command: Draw) -> tuple[Any, float | None] | None:
        """A frame and the world's last recompute time, or None when the field did not change."""
        world = self.table.get(command.world_id)
        if command.unless_field_version == world.field_version:
            return None
        frame = self.renderer.render(world, command.camera, command.options)
        return frame, self.table.last_recompute_ms.get(command.world_id)

    def pick(self, command: PickAt) -> tuple[Any, int]:
        world = self.table.get(command.world_id)
        return self.renderer.pick(world, command.camera, command.x, command.y), world.field_version

    @property
    def renderer(self) -> Renderer:
        """The engine's renderer, made on first use (engine thread only)."""
        if self._renderer is None:
            self._renderer = Renderer(self.gpu)
        return self._renderer

    def release(self) -> None:
        if self._renderer is not None:
            self._renderer.release()
            self._renderer = None
