"""Core test helpers: a seeded random generator and the distance oracle (the `gpu` fixture is
tests/conftest.py's)."""

from __future__ import annotations

import secrets

import numpy as np
import pytest
from scipy.ndimage import distance_transform_cdt


@pytest.fixture
def rng() -> np.random.Generator:
    seed = secrets.randbits(64)
    print(f"random seed: {seed}")  # shown by pytest when the test fails
    return np.random.default_rng(seed)


def oracle(voxels_zyx: np.ndarray, cap: int) -> np.ndarray:
    """The exact capped Manhattan distance, from scipy; outside the world is air."""
    if not voxels_zyx.any():
        return np.full(voxels_zyx.shape, cap, dtype=np.uint8)
    d = distance_transform_cdt(voxels_zyx == 0, metric="taxicab")
    return np.minimum(d, cap).astype(np.uint8)


def random_voxels(rng: np.random.Generator, shape_zyx, density: float) -> np.ndarray:
    solid = rng.random(shape_zyx) < density
    return np.where(solid, rng.integers(1, 256, shape_zyx), 0).astype(np.uint8)
