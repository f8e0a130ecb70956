"""Helpers for the client tests: paths, a free port, a real server, and NumPy oracles (edit
semantics, capped taxicab)."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import Iterator

import numpy as np
from scipy.ndimage import distance_transform_cdt

from server_process import ROOT, ServerProcess, checkout_env, free_port  # noqa: F401  (tests import them here)

CLIENTS = ROOT / "clients"
if str(CLIENTS) not in sys.path:
    sys.path.insert(0, str(CLIENTS))


def env_with_paths() -> dict[str, str]:
    """For the scripts the tests run: the checkout and clients/ on PYTHONPATH, no SDFSERVER_*."""
    return checkout_env(CLIENTS)


@contextlib.contextmanager
def serve(directory: Path, *flags: str) -> Iterator[str]:
    """Run ``sdfserver serve`` with ``flags`` and its data in ``directory``; yields its URL once ready."""
    server = ServerProcess(directory / "data", *flags).wait_ready()
    try:
        yield server.url
    finally:
        server.stop()


def apply_edits(voxels: np.ndarray, batch: list[dict]) -> None:
    """The edit semantics in NumPy, on a (z, y, x) uint8 array: boxes half-open, spheres |p-c| <= r."""
    sz, sy, sx = voxels.shape
    for e in batch:
        if e["op"] == "box":
            (x0, y0, z0), (x1, y1, z1) = e["min"], e["max"]
            voxels[max(z0, 0):max(z1, 0), max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = e["colour"]
        elif e["op"] == "sphere":
            z, y, x = np.ogrid[:sz, :sy, :sx]
            cx, cy, cz = e["center"]
            inside = (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2 <= e["radius"] ** 2
            voxels[inside] = e["colour"]
        elif e["op"] == "voxels":
            v = np.asarray(e["voxels"], dtype=np.int64)
            voxels[v[:, 2], v[:, 1], v[:, 0]] = v[:, 3]  # later rows win, as on the server
        else:
            raise ValueError(e["op"])


def oracle_distance(voxels: np.ndarray, cap: int) -> np.ndarray:
    """Manhattan distance to the nearest solid voxel, capped: scipy's taxicab transform."""
    empty = voxels == 0
    if empty.all():
        return np.full(voxels.shape, cap, dtype=np.int64)
    return np.minimum(distance_transform_cdt(empty, metric="taxicab"), cap)


def random_batch(rng: np.random.Generator, size: tuple[int, int, int]) -> list[dict]:
    """A few random brushes (integer centres and radii, so float rounding cannot matter)."""
    from sdfclient import edits

    batch = []
    for _ in range(int(rng.integers(1, 4))):
        colour = 0 if rng.random() < 0.3 else int(rng.integers(1, 256))
        kind = rng.integers(3)
        if kind == 0:
            centre = [int(rng.integers(0, s)) for s in size]
            batch.append(edits.sphere(centre, int(rng.integers(0, 7)), colour))
        elif kind == 1:
            lo = [int(rng.integers(-3, s)) for s in size]
            hi = [int(l + rng.integers(0, 10)) for l in lo]
            batch.append(edits.box(lo, hi, colour))
        else:
            n = int(rng.integers(1, 40))
            xyz = np.stack([rng.integers(0, s, n) for s in size], axis=1)
            batch.append(edits.voxels(np.concatenate([xyz, rng.integers(0, 256, (n, 1))], axis=1)))
    return batch
