"""Helpers for the client tests: paths, a free port, a real server, and NumPy oracles (edit
semantics, capped taxicab)."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import Iterator

import numpy as np

from references import apply_edits, oracle_distance  # noqa: F401  (tests import them here)
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
