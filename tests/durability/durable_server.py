"""Helpers of the durability tests: real `sdfserver serve` processes over a data directory the
test owns (started, killed with SIGKILL, restarted), and a NumPy reference of the box and
voxels edits the tests send."""

from __future__ import annotations

from pathlib import Path

import httpx
import numpy as np

import server_process
from references import apply_edits as apply_reference  # noqa: F401  (tests import it from here)

FLAGS = ["--memory-budget-bytes", str(32 << 20), "--no-warm-up", "--max-request-bytes", str(1 << 20),
         "--max-ops-per-batch", "64", "--max-brush-radius-vox", "40", "--max-wait-ms", "3000"]


class ServerProcess(server_process.ServerProcess):
    """A server with the durability tests' limits and an HTTP client (with ``token``, if given)."""

    def __init__(self, data_dir: Path, *flags: str, token: str | None = None, env: dict | None = None):
        super().__init__(data_dir, *FLAGS, *flags, env=env)
        headers = {"authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=self.url, timeout=30, headers=headers)

    def close(self) -> None:
        self.http.close()
        super().close()


def random_batch(rng: np.random.Generator, size: tuple[int, int, int]) -> list[dict]:
    sx, sy, sz = size
    ops = []
    for _ in range(int(rng.integers(1, 4))):
        if rng.random() < 0.5:
            n = int(rng.integers(1, 30))
            flat = rng.choice(sx * sy * sz, size=n, replace=False)
            z, y, x = np.unravel_index(flat, (sz, sy, sx))
            ops.append({"op": "voxels", "voxels": np.column_stack(
                [x, y, z, rng.integers(0, 256, n)]).tolist()})
        else:
            lo = [int(rng.integers(-2, s)) for s in size]
            ops.append({"op": "box", "min": lo, "max": [v + int(rng.integers(0, 6)) for v in lo],
                        "colour": int(rng.integers(0, 256))})
    return ops


def read_voxels(http: httpx.Client, world_id: str) -> tuple[int, np.ndarray]:
    r = http.get(f"/v1/worlds/{world_id}/voxels", headers={"accept": "application/octet-stream"})
    assert r.status_code == 200, r.text
    shape = tuple(int(v) for v in r.headers["x-sdf-shape"].split(","))
    return int(r.headers["x-sdf-version"]), np.frombuffer(r.content, np.uint8).reshape(shape)
