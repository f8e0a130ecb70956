"""Start-up: rebuild every stored world on the device before the engine thread starts.

For each world in the catalog, ``rebuild.restore_world`` (snapshot, replayed log, its store
open under a new epoch). A dense world's field is computed by the engine once it runs, in its
first step, or in pieces over several steps where that is long (``long_recomputes.py``): each
world serves as soon as its own field is back, and its commands wait until then. A world whose files fail their checks is refused — left
untouched on disk, answered with a storage error naming the file — and the others still load;
so is a world directory holding a log but no catalog entry (``Storage.orphans``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from sdfserver.engine.core import Engine
from sdfserver.engine.rebuild import config_from_dict, restore_world
from sdfserver.errors import CorruptData, SdfServerError
from sdfserver.storage import Storage
from sdfserver.storage.journal import StorageJournal

__all__ = ["RestoreReport", "config_from_dict", "restore_worlds"]
log = logging.getLogger("sdfserver.restore")


@dataclass
class RestoreReport:
    restored: list[str] = field(default_factory=list)
    refused: dict[str, str] = field(default_factory=dict)
    batches_replayed: int = 0
    elapsed_s: float = 0.0


def restore_worlds(engine: Engine, storage: Storage, journal: StorageJournal) -> RestoreReport:
    """Run on the thread that will start the engine, before ``engine.start()``."""
    report = RestoreReport()
    start = time.perf_counter()
    for world_id, reason in storage.orphans().items():
        _refuse(engine, report, world_id, CorruptData(reason, None, "a world's log and snapshots without its "
                                                      "catalog entry (world.json); restore it or remove the directory"))
    for world_id in storage.world_ids():
        try:
            restored = restore_world(engine.gpu, engine.limits, storage, world_id, recompute=False)
        except (SdfServerError, KeyError, TypeError, ValueError) as exc:
            _refuse(engine, report, world_id, exc)
            continue
        engine.adopt_world(world_id, restored.world, restored.owner, field_pending=not restored.recomputed)
        engine.batches.remember(world_id, restored.batch_ids)
        journal.adopt(world_id, restored.store, restored.owner)
        report.restored.append(world_id)
        report.batches_replayed += restored.replayed
    report.elapsed_s = time.perf_counter() - start
    log.info("restored %d worlds (%d logged batches replayed) in %.2f s; %d refused; the engine computes "
             "their fields as it starts, each world serving once its own is done",
             len(report.restored), report.batches_replayed, report.elapsed_s, len(report.refused))
    return report


def _refuse(engine: Engine, report: RestoreReport, world_id: str, exc: BaseException) -> None:
    reason = str(exc) if isinstance(exc, SdfServerError) else f"bad catalog entry: {exc!r}"
    log.error("world %s is NOT restored and stays untouched on disk: %s", world_id, reason)
    engine.refused[world_id] = reason
    report.refused[world_id] = reason
