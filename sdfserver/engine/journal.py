"""The durability hook the engine calls, if it is given one.

The engine calls these on its own thread, in the order things happen:

- ``record_create(world_id, config)`` after a world was created; ``config`` is the
  world's description as ``world_config_dict`` returns it (the body of
  ``POST /v1/worlds``: size, chunk_size, max_distance, algorithm, lod_algorithm, focus).
- ``record_batch(world_id, version, edits)`` after a batch passed validation and
  BEFORE it is applied and acknowledged; ``version`` is the version the batch will
  produce, ``edits`` the batch in wire form (a list of op maps as
  ``sdfserver.edits.parse_edits`` accepts; ``voxels`` as an (N, 4) integer NumPy
  array). If it raises, the batch is neither applied nor acknowledged.
- ``record_delete(world_id)`` after a world was deleted.

A journal must not call back into the engine.
"""

from __future__ import annotations

from typing import Any, Protocol


class Journal(Protocol):
    def record_create(self, world_id: str, config: dict[str, Any]) -> None: ...

    def record_batch(self, world_id: str, version: int, edits: list[dict[str, Any]]) -> None: ...

    def record_delete(self, world_id: str) -> None: ...
