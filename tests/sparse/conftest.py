"""Sparse-world test helpers: a seeded random generator, random edit batches as wire dicts (the
form tests/references.py replays) and a world pair fed the same batches."""

from __future__ import annotations

import secrets

import httpx
import numpy as np
import pytest

from sdfserver import wire


@pytest.fixture
def rng() -> np.random.Generator:
    seed = secrets.randbits(64)
    print(f"random seed: {seed}")  # shown by pytest when the test fails
    return np.random.default_rng(seed)


def random_batch(rng: np.random.Generator, size_xyz, brick: int) -> list[dict]:
    """Spheres and boxes that add or remove, centred near brick borders so they cross them, and a
    few explicit voxels."""
    size = np.asarray(size_xyz)
    borders = [rng.integers(0, s // brick + 1) * brick for s in size]
    batch = []
    for _ in range(int(rng.integers(1, 4))):
        colour = int(rng.choice([0, int(rng.integers(1, 256))], p=[0.3, 0.7]))
        centre = [float(b + rng.uniform(-3, 3)) for b in borders]
        if rng.random() < 0.5:
            batch.append({"op": "sphere", "center": centre, "radius": float(rng.uniform(0.5, 1.5 * brick)),
                          "colour": colour})
        else:
            lo = [int(c - rng.integers(1, brick + 2)) for c in centre]
            hi = [int(c + rng.integers(1, brick + 2)) for c in centre]
            batch.append({"op": "box", "min": lo, "max": hi, "colour": colour})
    rows = np.stack([rng.integers(0, s, 8) for s in size] + [rng.integers(0, 256, 8)], axis=1)
    batch.append({"op": "voxels", "voxels": rows.tolist()})
    return batch


def read(http: httpx.Client, world_id: str, what: str, lo, hi) -> np.ndarray:
    """A box of a world's ``field`` (packed) or ``voxels`` through the API, as an array."""
    params = {"min": ",".join(map(str, lo)), "max": ",".join(map(str, hi))}
    if what == "field":
        params["format"] = "packed"
    r = http.get(f"/v1/worlds/{world_id}/{what}", params=params, headers={"accept": wire.CONTENT_TYPE})
    assert r.status_code == 200, r.text
    msg = wire.decode(r.content)
    return np.frombuffer(msg["data"], dtype=msg["dtype"]).reshape(msg["shape"])
