"""The durability hook the engine calls, if it is given one.

The engine calls these on its own thread, in the order things happen:

- ``record_create(world_id, config, owner)`` after a world was created (an import adds
  ``voxels=`` and ``version=``, the world's initial voxels and version); ``config`` is the
  world's description as ``world_config_dict`` returns it (the body of
  ``POST /v1/worlds``: size, chunk_size, max_distance, algorithm, lod_algorithm, focus).
- ``record_batches(world_id, first_version, batches)`` once a step, for each world, with
  the batches that passed validation, BEFORE they are applied and acknowledged;
  ``first_version`` is the version the first batch will produce (the others follow,
  one each), each batch in wire form (a list of op maps as ``sdfserver.edits.parse_edits``
  accepts; ``voxels`` as an (N, 4) integer NumPy array) or as the bytes
  ``sdfserver.storage.codec.encode_batch`` made of that (an API process encodes it before
  sending it). If it raises, none of these
  batches is applied or acknowledged.
  It may return a ``concurrent.futures.Future`` (or an object with its ``done``,
  ``exception`` and ``add_done_callback``) that completes once the batches are durable;
  the engine then acknowledges them only when that future completes (and fails them if
  the future fails). Returning None acknowledges at once. Worlds whose records share one
  durable record may each return an object with that future as ``shared`` and their own
  refusal as ``fence()`` (``WorldDurable``): the engine then waits on ``shared`` once for all of
  them and asks each ``fence()`` after it completes.
- ``start_syncs()`` after the ``record_batches`` calls of a run of edit batches, before
  they are applied: what was recorded may start becoming durable now (the storage journal
  makes sure its committer has taken them, so the sync overlaps the engine's work; with
  ``wait=False``, when more commands are queued, it only wakes the committer).
- ``wait_durable(timeout_s)``: wait (letting go of the GIL) until what was recorded so far is
  durable and acknowledged, at most ``timeout_s``; True once it is. The engine calls it after
  applying a step's batches when no other command waits (a lone client's edit): the
  acknowledgement then goes out before the step's recompute takes the GIL, and that client's
  next read comes after the acknowledgement, so the recompute is still done first.
- ``record_config(world_id, config)`` before a reconfiguration takes effect
  (``reconfigure_durably``): if it raises, the world is left as it was.
- ``record_delete(world_id)`` after a world was deleted.
- ``wants_snapshot(world_id)`` after a world's recompute; when it answers True the
  engine calls ``record_snapshot(world_id, version, config, voxels, ready)`` with a host
  array (uint8, (z, y, x)) that a device copy is filling with the voxels at that version,
  and ``ready``, which waits until the copy is done: call it (from any thread) before
  reading ``voxels``. The engine does not wait for the copy, nor for the snapshot.

- ``epoch_of(world_id)``: the epoch under which this engine holds the world (0: none);
  ``fenced(world_id)``: whether another engine has taken it over since (its batches then
  fail with ``WorldFenced`` instead of being acknowledged); ``forget(world_id)``: drop a
  world taken over, its files left to their new holder.

A journal must not call back into the engine.
"""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import replace
from typing import Any, Callable, Protocol

import numpy as np


class Journal(Protocol):
    def record_create(self, world_id: str, config: dict[str, Any], owner: str | None = None, *,
                      voxels: np.ndarray | None = None, version: int = 0) -> None: ...

    def record_batches(self, world_id: str, first_version: int,
                       batches: list[list[dict[str, Any]] | bytes]) -> Future | None: ...

    def start_syncs(self, wait: bool = True) -> None: ...

    def wait_durable(self, timeout_s: float) -> bool: ...

    def record_config(self, world_id: str, config: dict[str, Any]) -> None: ...

    def record_delete(self, world_id: str) -> None: ...

    def wants_snapshot(self, world_id: str) -> bool: ...

    def epoch_of(self, world_id: str) -> int: ...

    def fenced(self, world_id: str) -> bool: ...

    def forget(self, world_id: str) -> None: ...

    def record_snapshot(self, world_id: str, version: int, config: dict[str, Any],
                        voxels: np.ndarray, ready: Callable[[], None]) -> Any: ...


def reconfigure_durably(journal: Journal | None, world_id: str, world: Any, changes: dict[str, Any],
                        as_dict: Callable[[Any], dict[str, Any]]) -> None:
    """``world.reconfigure(**changes)``, written to the journal first: a request changes all it
    asked or nothing. Should the world refuse the change after it was written (its seed
    buffers do not fit), the old configuration is written back."""
    if journal is None:
        world.reconfigure(**changes)
        return
    before = world.config
    journal.record_config(world_id, as_dict(replace(before, **changes).validated()))
    try:
        world.reconfigure(**changes)
    except BaseException:
        journal.record_config(world_id, as_dict(before))
        raise
