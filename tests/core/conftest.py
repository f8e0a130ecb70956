"""Core test helpers: a seeded random generator and the distance oracle (the `gpu` fixture is
tests/conftest.py's)."""

from __future__ import annotations

import secrets

import numpy as np
import pytest
from references import oracle_distance as oracle  # noqa: F401  (tests import it from here)


@pytest.fixture
def rng() -> np.random.Generator:
    seed = secrets.randbits(64)
    print(f"random seed: {seed}")  # shown by pytest when the test fails
    return np.random.default_rng(seed)


def random_voxels(rng: np.random.Generator, shape_zyx, density: float) -> np.ndarray:
    solid = rng.random(shape_zyx) < density
    return np.where(solid, rng.integers(1, 256, shape_zyx), 0).astype(np.uint8)
