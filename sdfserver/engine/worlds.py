"""The world table: every World of one engine, its owner, its last recompute, and the worlds on
disk that could not be restored. The engine thread writes it; owners are read by any thread (a
dict read is atomic)."""

from __future__ import annotations

import secrets
from dataclasses import asdict, replace
from typing import Any

from sdfserver import recompute_cost
from sdfserver.engine.commands import CreateWorld, EngineLimits
from sdfserver.engine.describe import describe_recompute
from sdfserver.engine.journal import Journal, reconfigure_durably
from sdfserver.engine.metrics import EngineMetrics
from sdfserver.errors import InvalidInput, NotFound, StorageError, TooLarge, WorldMoved
from sdfserver.gpu import GpuContext
from sdfserver.storage.sparse_snapshot import SparseContent
from sdfserver.world import World, WorldConfig
from sdfserver.world_factory import make_world


MAX_TOMBSTONES = 4096  # worlds that moved away, remembered to answer WorldMoved (not NotFound)


def world_config_dict(config: WorldConfig) -> dict[str, Any]:
    """A WorldConfig in wire form (the body of ``POST /v1/worlds``)."""
    d = asdict(config)
    d["size"] = list(config.size)
    if config.focus is not None:
        d["focus"] = {"center": list(config.focus.center), "size": list(config.focus.size)}
    d["origin"] = list(config.origin)
    if config.palette is not None:
        d["palette"] = [list(c) for c in config.palette]
    return d


def new_world_id() -> str:
    # Hex, not url-safe base64: an id that starts with '-' reads as an option on command lines.
    return secrets.token_hex(6)


class WorldTable:
    def __init__(self, gpu: GpuContext, limits: EngineLimits, journal: Journal | None, metrics: EngineMetrics):
        self.gpu = gpu
        self.limits = limits
        self.journal = journal
        self.metrics = metrics
        self.worlds: dict[str, World] = {}
        self.owners: dict[str, str | None] = {}
        self.refused: dict[str, str] = {}  # worlds on disk that could not be restored, and why
        self.gone: dict[str, str] = {}  # worlds that moved to another engine, and how
        self.last_recompute_ms: dict[str, float] = {}

    def get(self, world_id: str) -> World:
        try:
            return self.worlds[world_id]
        except (KeyError, TypeError):
            if isinstance(world_id, str) and world_id in self.refused:
                raise StorageError(f"world {world_id!r} was not restored: {self.refused[world_id]}") from None
            if isinstance(world_id, str) and world_id in self.gone:
                raise WorldMoved(self.gone[world_id]) from None
            raise NotFound(f"no world {world_id!r}") from None

    def owner_of(self, world_id: str) -> str | None:
        """The owning key's name (any thread); NotFound for an unknown world."""
        try:
            return self.owners[world_id]
        except KeyError:
            self.get(world_id)
            raise NotFound(f"no world {world_id!r}") from None

    def create(self, command: CreateWorld) -> str:
        """A new world (journaled); its id."""
        config = command.config.validated()
        sx, sy, sz = config.size
        # A sparse world's memory follows its stored bricks, checked against the budget as they come.
        if config.storage == "dense" and sx * sy * sz > self.limits.max_world_voxels:
            raise TooLarge(f"a {sx}x{sy}x{sz} world has {sx * sy * sz} voxels; the limit is "
                           f"{self.limits.max_world_voxels}")
        recompute_cost.check(config, self.limits.max_recompute_voxel_visits)
        if len(self.worlds) >= self.limits.max_worlds:
            raise TooLarge(f"the server already holds {len(self.worlds)} worlds, its limit")
        world_id = command.world_id or new_world_id()
        while world_id in self.worlds or (not command.world_id and world_id in self.gone):
            if command.world_id:
                raise InvalidInput(f"world {world_id!r} already exists")
            world_id = new_world_id()
        if command.voxels is not None and (config.storage == "sparse") != isinstance(command.voxels, SparseContent):
            raise InvalidInput("a sparse world imports a sparse world's snapshot (its bricks), a dense one voxels")
        world = make_world(self.gpu, config, self.limits.edits, generate=command.voxels is None)
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
        self.adopt(world_id, world, command.owner)
        return world_id

    def adopt(self, world_id: str, world: World, owner: str | None) -> None:
        self.worlds[world_id] = world
        self.owners[world_id] = owner
        self.gone.pop(world_id, None)
        self.count()

    def forget(self, world_id: str, why: str) -> None:
        """The world leaves this engine (moved to another): off the device, its files left alone."""
        world = self.worlds.pop(world_id)
        self.owners.pop(world_id, None)
        self.last_recompute_ms.pop(world_id, None)
        self.gone[world_id] = why
        while len(self.gone) > MAX_TOMBSTONES:
            self.gone.pop(next(iter(self.gone)))
        world.release()
        self.count()

    def delete(self, world_id: str) -> None:
        world = self.get(world_id)
        if self.journal is not None:
            self.journal.record_delete(world_id)
        del self.worlds[world_id]
        self.owners.pop(world_id, None)
        self.last_recompute_ms.pop(world_id, None)
        world.release()
        self.count()

    def reconfigure(self, world_id: str, changes: dict[str, Any]) -> None:
        """Written to the journal before it takes effect: a request changes all it asked or nothing.
        A change that recomputes the field is refused first when that recompute would cost more
        than the limit."""
        world = self.get(world_id)
        field_changes = {k: v for k, v in changes.items() if k in World.FIELD_CHANGES and v != "keep"}
        if field_changes:
            config = replace(world.config, **field_changes).validated()
            if any(getattr(config, k) != getattr(world.config, k) for k in field_changes):
                recompute_cost.check(config, self.limits.max_recompute_voxel_visits)
        reconfigure_durably(self.journal, world_id, self.get(world_id), changes, world_config_dict)

    def describe(self, world_id: str | None) -> Any:
        """One world's description, or every world's (``None``)."""
        if world_id is None:
            return [self.describe(i) for i in sorted(self.worlds)]
        world = self.get(world_id)
        return {
            "id": world_id,
            **world_config_dict(world.config),
            "version": world.version,
            "field_version": world.field_version,
            "dirty_chunks": world.dirty_chunk_count,
            "last_recompute_ms": self.last_recompute_ms.get(world_id),
            "last_recompute": describe_recompute(world.last_recompute),
            "device_bytes": world.device_bytes,
            **({"stored_bricks": world.stored_bricks, "bytes_per_stored_voxel": world.bytes_per_stored_voxel}
               if world.config.storage == "sparse" else {}),
            "owner": self.owners.get(world_id),
            "epoch": self.journal.epoch_of(world_id) if self.journal is not None else 0,
        }

    def release_all(self) -> None:
        for world in self.worlds.values():
            world.release()
        self.worlds.clear()

    def count(self) -> None:
        self.metrics.worlds.set(len(self.worlds))
        self.metrics.device_bytes.set(sum(w.device_bytes for w in self.worlds.values()))
