"""Core test helpers: a seeded random generator, the distance oracles, random edit batches and a
check that a world edited step by step keeps scipy's field (the `gpu` fixture is
tests/conftest.py's)."""

from __future__ import annotations

import secrets

import numpy as np
import pytest
from references import field_distances
from references import oracle_distance as oracle  # noqa: F401  (tests import it from here)

from sdfserver.edits import BoxEdit, SphereEdit, VoxelsEdit


@pytest.fixture
def rng() -> np.random.Generator:
    seed = secrets.randbits(64)
    print(f"random seed: {seed}")  # shown by pytest when the test fails
    return np.random.default_rng(seed)


def random_voxels(rng: np.random.Generator, shape_zyx, density: float) -> np.ndarray:
    solid = rng.random(shape_zyx) < density
    return np.where(solid, rng.integers(1, 256, shape_zyx), 0).astype(np.uint8)


def stored_field(voxels: np.ndarray, cap: int, metric: str, signed: bool) -> np.ndarray:
    """The stored value scipy gives (references.field_distances): Manhattan (distance << 8) |
    colour, Euclidean the squared distance; capped; signed solids carry their distance to air."""
    d = np.abs(field_distances(voxels, metric, signed, cap))
    if metric == "euclidean":
        return np.rint(d * d).astype(np.int64)
    return (d.astype(np.int64) << 8) | voxels


def random_batch(rng: np.random.Generator, size, first: bool) -> list:
    """Voxels that add and, after the first batch, may erase; a sphere, sometimes past a face,
    and a small box, each of which may erase."""
    n = int(rng.integers(1, 60))
    xyz = np.stack([rng.integers(0, s, n) for s in size], axis=1)
    colours = rng.integers(1 if first else 0, 256, n)
    centre = tuple(float(rng.uniform(-2, s + 2)) for s in size)  # sometimes past a face
    lo = [int(rng.integers(0, s - 4)) for s in size]
    return [VoxelsEdit(np.concatenate([xyz, colours[:, None]], axis=1).astype(np.int64)),
            SphereEdit(center=centre, radius=float(rng.uniform(1, 10)), colour=int(rng.integers(0, 3))),
            BoxEdit(min=tuple(lo), max=tuple(v + int(rng.integers(1, 5)) for v in lo), colour=int(rng.integers(0, 2)))]


def edit_and_compare(world, rng: np.random.Generator, size, steps: int, cap: int, metric: str, signed: bool,
                     full: bool = True) -> None:
    """``steps`` random batches, each recomputed and its field compared with scipy's; with
    ``full``, then a full transform that must give the same field."""
    for step in range(steps):
        world.apply_edits(random_batch(rng, size, step == 0))
        world.recompute()
        got = world.read_field().astype(np.int64)
        bad = np.argwhere(got != stored_field(world.read_voxels(), cap, metric, signed))
        assert bad.size == 0, f"step {step}: {len(bad)} voxels differ, first (z, y, x) {bad[:3].tolist()}"
    if full:
        incremental = world.read_field()
        world.mark_all_dirty()
        world.recompute()
        assert np.array_equal(world.read_field(), incremental)
