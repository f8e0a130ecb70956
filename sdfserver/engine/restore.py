"""Start-up: rebuild every stored world on the device before the engine thread starts.

For each world in the catalog: recover its snapshot and log (``Storage.open_world``), load
the snapshot's voxels, replay the logged batches in version order (each through
``parse_edits`` and ``World.apply_edits``, as when they arrived, but under ``REPLAY_LIMITS``:
a batch that was accepted once is applied whatever today's limits are), then recompute the
whole distance field on the device. A world whose files fail their checks is refused — left
untouched on disk, answered with a storage error naming the file — and the others still load;
so is a world directory holding a log but no catalog entry (``Storage.orphans``).

``config_from_dict`` reads a configuration from a catalog entry or an uploaded snapshot: a
focus beyond the range requests may carry (which older servers accepted) is narrowed to the
same chunks of the world, so that every description of the world can be encoded.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

from sdfserver.edits import REPLAY_LIMITS, parse_edits
from sdfserver.engine.core import Engine
from sdfserver.errors import CorruptData, SdfServerError
from sdfserver.storage import Storage, batch_parts, decode_batch
from sdfserver.storage.journal import StorageJournal
from sdfserver.world import Focus, World, WorldConfig
from sdfserver.world_config import TerrainSpec
from sdfserver.world_factory import make_world

log = logging.getLogger("sdfserver.restore")
REPLAY_GROUP = 1024  # batches planned before a group's launches; a step under load brings ~30


@dataclass
class RestoreReport:
    restored: list[str] = field(default_factory=list)
    refused: dict[str, str] = field(default_factory=dict)
    batches_replayed: int = 0
    elapsed_s: float = 0.0


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
                       generate=None if d.get("generate") is None else TerrainSpec(**d["generate"]))


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


def restore_worlds(engine: Engine, storage: Storage, journal: StorageJournal) -> RestoreReport:
    """Run on the thread that will start the engine, before ``engine.start()``."""
    report = RestoreReport()
    start = time.perf_counter()
    for world_id, reason in storage.orphans().items():
        _refuse(engine, report, world_id, CorruptData(reason, None, "a world's log and snapshots without its "
                                                      "catalog entry (world.json); restore it or remove the directory"))
    for world_id in storage.world_ids():
        try:
            meta = storage.read_meta(world_id)
            store, recovered = storage.open_world(world_id)
        except SdfServerError as exc:
            _refuse(engine, report, world_id, exc)
            continue
        world = None
        try:
            world = make_world(engine.gpu, config_from_dict(meta["config"]), REPLAY_LIMITS,
                               generate=recovered.voxels is None)
            if recovered.voxels is not None:
                world.load_voxels(recovered.voxels)
            world.version = recovered.snapshot_version
            engine.batches.remember(world_id, _replay(world, recovered.records, store.directory))
            world.limits = engine.limits.edits  # what comes in from now on meets today's limits
            world.recompute()
        except (SdfServerError, KeyError, TypeError, ValueError) as exc:
            store.close()
            if world is not None:
                world.release()
            _refuse(engine, report, world_id, exc)
            continue
        if recovered.torn:
            log.warning("world %s: %s", world_id, recovered.torn)
        engine.adopt_world(world_id, world, meta.get("owner"))
        journal.adopt(world_id, store, meta.get("owner"))
        report.restored.append(world_id)
        report.batches_replayed += len(recovered.records)
    report.elapsed_s = time.perf_counter() - start
    log.info("restored %d worlds (%d logged batches replayed) in %.2f s; %d refused",
             len(report.restored), report.batches_replayed, report.elapsed_s, len(report.refused))
    return report


def _replay(world: World, records: list[tuple[int, bytes]], directory: Path) -> list[tuple[str, int]]:
    """Apply the logged batches in order; CorruptData names the first one that does not apply.
    Returns the (batch id, version) of those that carry an id."""
    ids = []
    for start in range(0, len(records), REPLAY_GROUP):
        plans = []
        for version, payload in records[start:start + REPLAY_GROUP]:
            where = f"{directory} record {version}"
            try:
                edits_wire, batch_id = batch_parts(decode_batch(payload, where))
                plans.append(world.plan_edits(parse_edits(edits_wire)))
                if batch_id is not None:
                    ids.append((batch_id, version))
            except SdfServerError as exc:
                raise CorruptData(where, None, f"logged batch does not apply: {exc}") from None
        world.apply_plans(plans)
        if world.config.storage == "sparse":  # its pending edits make one scratch box: keep them few
            world.recompute()
    return ids


def _refuse(engine: Engine, report: RestoreReport, world_id: str, exc: BaseException) -> None:
    reason = str(exc) if isinstance(exc, SdfServerError) else f"bad catalog entry: {exc!r}"
    log.error("world %s is NOT restored and stays untouched on disk: %s", world_id, reason)
    engine.refused[world_id] = reason
    report.refused[world_id] = reason
