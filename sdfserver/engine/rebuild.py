"""One stored world rebuilt on the device: its snapshot's voxels loaded, its logged batches
replayed in version order (each through ``codec.decode_edits`` and the world's edit planning, as when
they arrived, but under ``REPLAY_LIMITS``: a batch that was accepted once is applied whatever
today's limits are), then its whole distance field recomputed: here when a world moves to this
engine (``moves.py``); at start-up (``restore.py``) by the running engine, so that one heavy
world does not keep the others from serving.

``config_from_dict`` reads a configuration from a catalog entry or an uploaded snapshot: a
focus beyond the range requests may carry (which older servers accepted) is narrowed to the
same chunks of the world, so that every description of the world can be encoded.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from sdfserver.edits import REPLAY_LIMITS
from sdfserver.engine.commands import EngineLimits
from sdfserver.errors import CorruptData, SdfServerError
from sdfserver.gpu import GpuContext
from sdfserver.storage import Storage
from sdfserver.storage.codec import decode_edits
from sdfserver.storage.store import WorldStore
from sdfserver.world import Focus, World, WorldConfig
from sdfserver.world_config import TerrainSpec
from sdfserver.world_factory import make_world

log = logging.getLogger("sdfserver.restore")
REPLAY_GROUP = 1024  # batches planned before a group's launches; a step under load brings ~30

FOCUS_LIMIT = (1 << 31) - 1  # the focus values a request may carry (api/models.py)


def config_from_dict(d: dict) -> WorldConfig:
    """A configuration from its dict form; raises KeyError, TypeError or ValueError when it is
    not one (validation of the values is ``WorldConfig.validated``'s)."""
    size = tuple(d["size"])
    chunk_size = d["chunk_size"]
    if len(size) != 3 or not all(isinstance(v, int) and 0 < v <= FOCUS_LIMIT for v in size) \
            or not isinstance(chunk_size, int) or chunk_size <= 0:
        raise ValueError(f"size {list(size)[:3]} and chunk_size must be positive integers")
    return WorldConfig(size=size, chunk_size=chunk_size, max_distance=d["max_distance"],
                       algorithm=d["algorithm"], lod_algorithm=d.get("lod_algorithm", "jfa"),
                       borders=d.get("borders", "exact"),  # older logs and snapshots predate it
                       focus=_focus(d.get("focus"), size, chunk_size), storage=d.get("storage", "dense"),
                       generate=None if d.get("generate") is None else TerrainSpec(**d["generate"]),
                       # older logs and snapshots predate these: Manhattan, unsigned, unit voxels, RGB332
                       metric=d.get("metric", "manhattan"), signed=d.get("signed", False),
                       voxel_size=d.get("voxel_size", 1.0), origin=tuple(d.get("origin", (0.0, 0.0, 0.0))),
                       palette=d.get("palette"))


def _focus(focus: dict | None, size: tuple, chunk_size: int) -> Focus | None:
    """The focus, or the one that covers the same chunks of the world with values in range."""
    if focus is None:
        return None
    center, extent = tuple(focus["center"]), tuple(focus["size"])
    if len(center) != 3 or len(extent) != 3 or not all(isinstance(v, int) for v in center + extent):
        raise ValueError(f"focus center and size must be three integers each, got {focus!r}")
    if all(-FOCUS_LIMIT <= v <= FOCUS_LIMIT for v in center + extent):
        return Focus(center, extent)
    if min(extent) <= 0:
        raise ValueError("focus size must be positive")
    lo, hi = [], []
    for c, s, n in zip(center, extent, (v // chunk_size for v in size)):
        a = min(max(c - s // 2, -1), n + 1)  # one chunk of margin keeps a focus beside the world outside it
        b = min(max(c - s // 2 + s, -1), n + 1)
        if b <= a:
            b = a + 1
        lo.append(a)
        hi.append(b)
    return Focus(tuple(a + (b - a) // 2 for a, b in zip(lo, hi)), tuple(b - a for a, b in zip(lo, hi)))


@dataclass
class Restored:
    world: World
    store: WorldStore
    owner: str | None
    batch_ids: list[tuple[str, int]]  # (Idempotency-Key, version) of the logged batches that carry one
    replayed: int
    recomputed: bool = True  # False: its field is still to be computed (restore_world's recompute)


def restore_world(gpu: GpuContext, limits: EngineLimits, storage: Storage, world_id: str,
                  recompute: bool = True) -> Restored:
    """One stored world rebuilt on the device (its store open under a new epoch); raises what
    refuses it (``SdfServerError``, or KeyError/TypeError/ValueError for a bad catalog entry),
    leaving nothing open. ``recompute=False``: a dense world's field is left to the engine
    (``Restored.recomputed`` False, the whole world dirty); a sparse world's is made here."""
    meta = storage.read_meta(world_id)
    store, recovered = storage.open_world(world_id)
    world = None
    try:
        world = make_world(gpu, config_from_dict(meta["config"]), REPLAY_LIMITS, generate=recovered.voxels is None)
        if recovered.voxels is not None:
            world.load_voxels(recovered.voxels)
        world.version = recovered.snapshot_version
        batch_ids = _replay(world, recovered.records, store.directory)
        world.limits = limits.edits  # what comes in from now on meets today's limits
        recomputed = recompute or world.config.storage == "sparse"
        if recomputed:
            world.recompute()
        else:
            world.mark_all_dirty()
    except BaseException:
        store.close()
        if world is not None:
            world.release()
        raise
    if recovered.torn:
        log.warning("world %s: %s", world_id, recovered.torn)
    return Restored(world, store, meta.get("owner"), batch_ids, len(recovered.records), recomputed)


def _replay(world: World, records: list[tuple[int, bytes]], directory: Path) -> list[tuple[str, int]]:
    """Apply the logged batches in order; CorruptData names the first one that does not apply.
    Returns the (batch id, version) of those that carry an id."""
    ids = []
    for start in range(0, len(records), REPLAY_GROUP):
        plans = []
        for version, payload in records[start:start + REPLAY_GROUP]:
            where = f"{directory} record {version}"
            try:
                edits, batch_id = decode_edits(payload, where)
                plans.append(world.plan_edits(edits))
                if batch_id is not None:
                    ids.append((batch_id, version))
            except SdfServerError as exc:
                raise CorruptData(where, None, f"logged batch does not apply: {exc}") from None
        world.apply_plans(plans)
        if world.config.storage == "sparse":  # its pending edits make one scratch box: keep them few
            world.recompute()
    return ids
