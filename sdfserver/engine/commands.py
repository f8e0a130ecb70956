"""What request handlers ask of the engine, and what it answers.

Commands are plain data; the engine thread executes them. ``APPLY`` commands
change worlds and run first in a step, in arrival order; the others run after
the step's recompute, so they see every edit applied before them.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal

import msgspec
import numpy as np

from sdfserver.edits import Edit, EditLimits
from sdfserver.geometry import Box, Vec3
from sdfserver.world import WorldConfig

from sdfserver.engine.mailbox import Subscription

ReadKind = Literal["packed", "distance", "voxels"]
log = logging.getLogger("sdfserver.engine")


@dataclass(frozen=True)
class EngineLimits:
    edits: EditLimits = field(default_factory=EditLimits)
    max_world_voxels: int = 1 << 30
    max_worlds: int = 64
    max_read_voxels: int = 1 << 27
    max_subscription_voxels: int = 1 << 27
    max_subscriptions: int = 1024  # held by the engine at once, every client together
    max_subscriptions_per_key: int = 64  # held by one API key (or one client address on an open server)
    max_wait_s: float = 5.0
    slow_step_ms: float = 20.0  # a step this long is logged with its phases
    # a create, import or reconfiguration whose full recompute would pass this many voxel visits
    # is refused (recompute_cost.py); None: no limit
    max_recompute_voxel_visits: int | None = None
    busy_step_ms: float = 20.0  # /readyz and /metrics show a step running longer than this
    # how long a step may run recomputes in pieces (long_recomputes.py), other worlds served between
    step_budget_ms: float = 8.0


@dataclass(frozen=True)
class CreateWorld:
    config: WorldConfig
    world_id: str | None = None  # None: a fresh random id (restore passes the old one)
    owner: str | None = None  # the API key name that owns the world (None: open server)
    voxels: np.ndarray | None = None  # initial voxels, uint8 (z, y, x): an import, version 1


@dataclass(frozen=True)
class DeleteWorld:
    world_id: str


@dataclass(frozen=True)
class Reconfigure:
    world_id: str
    changes: dict[str, Any]  # keyword arguments of World.reconfigure


@dataclass(frozen=True)
class ReleaseWorld:
    world_id: str
    destination: Path  # the data directory of the engine that takes it (moves.py)


@dataclass(frozen=True)
class AdoptWorld:
    world_id: str
    source: Path | None  # the data directory it comes from if its holder did not hand it over


class ApplyEdits(msgspec.Struct, frozen=True):  # one a batch: a struct is made faster than a dataclass
    world_id: str
    edits: list[Edit]
    # the batch as it arrived, for the journal; or its log record already encoded
    # (storage.codec.encode_batch), as an API process sends it
    wire: list[dict[str, Any]] | bytes
    batch_id: str | None = None  # the client's id: a batch seen before is answered, not applied again


@dataclass(frozen=True)
class Describe:
    world_id: str | None  # None: every world


@dataclass(frozen=True)
class Read:
    world_id: str
    kind: ReadKind
    box: Box | None = None  # None: the whole world
    min_version: int = 0
    deadline: float = 0.0  # time.monotonic() after which an unmet min_version fails


@dataclass(frozen=True)
class Query:
    world_id: str
    rows: np.ndarray  # (N, columns) in world units: engine/query.py's KINDS[kind]
    min_version: int = 0
    deadline: float = 0.0
    kind: str = "points"  # points, spheres or rays


@dataclass(frozen=True)
class Subscribe:
    subscription: Subscription


@dataclass(frozen=True)
class Draw:
    """Render a frame of a world; None when the field is still at ``unless_field_version``."""

    world_id: str
    camera: Any  # render.Camera
    options: Any  # render.RenderOptions
    unless_field_version: int | None = None


@dataclass(frozen=True)
class PickAt:
    world_id: str
    camera: Any  # render.Camera
    x: float
    y: float


@dataclass(frozen=True)
class CopyBricks:
    """A sparse world's bricks as they are now (an export): (version, configuration, SparseContent,
    wait), the content to read only after ``wait()`` (its device copy)."""

    world_id: str


@dataclass(frozen=True)
class OnDevice:
    """A function run on the engine thread: for tests and tools inside the engine's process."""

    fn: Callable[[], Any]


APPLY = (CreateWorld, DeleteWorld, Reconfigure, ReleaseWorld, AdoptWorld, ApplyEdits)


class CommandCalls:
    """The hot calls as commands: a subclass supplies ``call`` (run one command, return its
    result) and ``max_wait_s``."""

    max_wait_s: float

    async def call(self, command: Any) -> Any:
        raise NotImplementedError

    async def apply_edits(self, world_id: str, edits: list[Edit], wire: list[dict[str, Any]]) -> int:
        return await self.call(ApplyEdits(world_id, edits, wire))

    async def read(self, world_id: str, kind: ReadKind, box: Box | None = None, min_version: int = 0) -> "ReadResult":
        return await self.call(Read(world_id, kind, box, min_version, self._deadline()))

    async def query(self, world_id: str, rows: np.ndarray, min_version: int = 0, kind: str = "points") -> Any:
        return await self.call(Query(world_id, rows, min_version, self._deadline(), kind))

    def _deadline(self) -> float:
        return time.monotonic() + self.max_wait_s


@dataclass(frozen=True)
class ReadResult:
    origin: Vec3  # (x, y, z) of element [0, 0, 0]
    version: int  # voxels: the world's version; field: the version the field reflects
    array: np.ndarray  # C-ordered (z, y, x)
    # "voxels", "distance" (field_values.distance_dtype), or what a packed read carries
    # (field_values.packed_content: "distance_colour" or "squared_distance")
    content: str = ""


@dataclass
class StepReport:
    applied_batches: int = 0
    rejected_batches: int = 0
    recomputed: dict[str, Any] = field(default_factory=dict)  # world id -> RecomputeResult
    served: int = 0
    waiting: int = 0
    phases_ms: dict[str, float] = field(default_factory=dict)  # apply, recompute, publish, serve
    cpu_ms: float = 0.0  # the engine thread's CPU time in the step (the rest: waiting, for the GIL among others)
    user_ms: float = 0.0  # the kernel's user/system split of the thread's CPU time (sampled at ticks: rough)
    system_ms: float = 0.0
    page_faults: int = 0  # the engine thread's page faults in the step, minor and major
    preempted: int = 0  # times the kernel took the engine thread's CPU away in the step
    # within apply: validating batches (plan), handing them to the log (log), launching their edits
    # (launch), the rest of applying them (acknowledge); logged with a slow step
    apply_ms: dict[str, float] = field(
        default_factory=lambda: dict.fromkeys(("plan", "log", "launch", "acknowledge"), 0.0))
