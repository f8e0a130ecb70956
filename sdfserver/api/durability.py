"""What ``sdfserver serve`` adds for durable worlds: open the data directory, give the
engine its journal, restore the stored worlds before the engine starts."""

from __future__ import annotations

from sdfserver.engine import Engine
from sdfserver.engine.restore import RestoreReport, restore_worlds
from sdfserver.settings import Settings
from sdfserver.storage import Storage
from sdfserver.storage.journal import StorageJournal


def open_journal(settings: Settings) -> StorageJournal | None:
    if not settings.persist:
        return None
    storage = Storage(settings.data_dir, sync=settings.sync, commit_window_ms=settings.commit_window_ms,
                      sync_inline=settings.sync_inline)
    return StorageJournal(storage, snapshot_every_batches=settings.snapshot_every_batches,
                          snapshot_min_interval_s=settings.snapshot_min_interval_s)


def restore(engine: Engine, journal: StorageJournal) -> RestoreReport:
    return restore_worlds(engine, journal.storage, journal)
