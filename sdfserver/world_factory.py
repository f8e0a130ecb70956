"""A world of either storage from its configuration: ``World`` (dense) or ``SparseWorld``."""

from __future__ import annotations

from sdfserver.edits import EditLimits
from sdfserver.gpu import GpuContext
from sdfserver.sparse.world import SparseWorld
from sdfserver.world import World
from sdfserver.world_config import WorldConfig

AnyWorld = World | SparseWorld


def make_world(gpu: GpuContext, config: WorldConfig, limits: EditLimits = EditLimits(),
               generate: bool = True) -> AnyWorld:
    """Validate ``config`` and build its world (a generated one's terrain included, unless
    ``generate`` is False: a snapshot about to replace it)."""
    config = config.validated()
    if config.storage == "sparse":
        return SparseWorld(gpu, config, limits, generate)
    return World(gpu, config, limits)
