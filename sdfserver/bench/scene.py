"""The scene every benchmark measures: the dissertation's benchmark mode (§3.5), brushes at random
places and sizes, most placing and some erasing, from a seeded generator so that two builds or two
devices measure the same world."""

from __future__ import annotations

import numpy as np

from sdfserver.edits import SphereEdit
from sdfserver.world import World


def random_brushes(rng: np.random.Generator, size, count: int, max_radius: float) -> list[SphereEdit]:
    """``count`` spheres of radius 1..``max_radius`` anywhere in ``size``; four in five place a colour."""
    centers = rng.uniform(0, 1, (count, 3)) * np.asarray(size)
    radii = rng.uniform(1, max(1.5, max_radius), count)
    colours = np.where(rng.random(count) < 0.8, rng.integers(1, 256, count), 0)
    return [SphereEdit(tuple(map(float, c)), float(r), int(k)) for c, r, k in zip(centers, radii, colours)]


def populate(world: World, rng: np.random.Generator, brushes_per_chunk: float = 0.5) -> None:
    """Paints ``world`` with ``brushes_per_chunk`` brushes a chunk (at least four), each up to half
    a chunk across, in batches the world's limits admit."""
    size = world.config.size
    chunks = int(np.prod(world.config.chunks))
    count = max(4, int(chunks * brushes_per_chunk))
    brushes = random_brushes(rng, size, count, world.config.chunk_size / 2)
    step = world.limits.max_ops_per_batch
    for i in range(0, len(brushes), step):
        world.apply_edits(brushes[i:i + step])
