"""A real `sdfserver serve` process on loopback, shared by every test in this directory, and
NumPy/SciPy references to check what it answers."""

from __future__ import annotations

import subprocess
from typing import Any

import httpx
import numpy as np
import pytest

from sdfserver import wire

from references import apply_edits as apply_reference
from references import oracle_distance as distance_reference
from server_process import ServerProcess, tree_rss_bytes

MEMORY_BUDGET_BYTES = 32 << 20
SERVER_FLAGS = [
    "--memory-budget-bytes", str(MEMORY_BUDGET_BYTES),
    "--max-request-bytes", str(1 << 20),
    "--max-ops-per-batch", "64",
    "--max-voxels-per-batch", "20000",
    "--max-brush-radius-vox", "40",
    "--max-world-voxels", str(1 << 24),
    "--max-read-voxels", str(64 ** 3),
    "--max-query-points", "1000",
    "--max-wait-ms", "1500",
]


class Server:
    def __init__(self, process: subprocess.Popen, url: str):
        self.process = process
        self.url = url
        self.http = httpx.Client(base_url=url, timeout=30)

    @property
    def ws_url(self) -> str:
        return self.url.replace("http://", "ws://")

    def rss_bytes(self) -> int:
        """The server's memory: the launcher, its engine and its API processes."""
        return tree_rss_bytes(self.process.pid)

    def metric(self, name: str) -> float:
        for line in self.http.get("/metrics").text.splitlines():
            if line.startswith(name + " "):
                return float(line.split()[1])
        raise KeyError(name)

    # -- the API, in msgpack ---------------------------------------------------------------------

    def post(self, path: str, body: Any, **kw) -> httpx.Response:
        return self.http.post(path, content=wire.encode(body),
                              headers={"content-type": wire.CONTENT_TYPE, "accept": wire.CONTENT_TYPE}, **kw)

    def create_world(self, **body) -> dict:
        r = self.http.post("/v1/worlds", json=body)
        assert r.status_code == 201, r.text
        return r.json()

    def edit(self, world_id: str, edits: list, as_json: bool = False) -> int:
        if as_json:
            r = self.http.post(f"/v1/worlds/{world_id}/edits", json={"edits": edits})
            assert r.status_code == 200, r.text
            return r.json()["version"]
        r = self.post(f"/v1/worlds/{world_id}/edits", {"edits": edits})
        assert r.status_code == 200, r.text
        return wire.decode(r.content)["version"]

    def read(self, world_id: str, what: str = "field", min_version: int = 0, **params) -> tuple[np.ndarray, dict]:
        r = self.http.get(f"/v1/worlds/{world_id}/{what}", params={"min_version": min_version, **params},
                          headers={"accept": wire.CONTENT_TYPE})
        assert r.status_code == 200, r.text
        msg = wire.decode(r.content)
        array = np.frombuffer(msg["data"], dtype=msg["dtype"]).reshape(msg["shape"])
        return array, msg

    def state(self, world_id: str) -> tuple[int, bytes]:
        """(version, voxel bytes): what a rejected request must leave alone."""
        version = self.http.get(f"/v1/worlds/{world_id}").json()["version"]
        voxels, _ = self.read(world_id, "voxels")
        return version, voxels.tobytes()


@pytest.fixture(scope="session", params=[1, 2], ids=["one-worker", "two-workers"])
def server(request, tmp_path_factory) -> Server:
    """Every test here runs against one API process and two (any route in any process)."""
    # A data directory of its own: worlds are durable, and servers sharing one would see each
    # other's leftovers.
    process = ServerProcess(tmp_path_factory.mktemp("api-server") / "data", *SERVER_FLAGS,
                            "--workers", str(request.param)).wait_ready()
    srv = Server(process.process, process.url)
    yield srv
    srv.http.close()
    process.stop()


# -- references -------------------------------------------------------------------------------------


def random_batch(rng: np.random.Generator, size: tuple[int, int, int], blob: bool = True) -> list[dict]:
    """A few random operations; spheres use integer centres and radius k + 0.5 (no ties)."""
    sx, sy, sz = size
    ops: list[dict] = []
    for _ in range(int(rng.integers(1, 4))):
        kind = rng.choice(["voxels", "box", "sphere"])
        colour = int(rng.choice([0, int(rng.integers(1, 256))], p=[0.25, 0.75]))
        if kind == "voxels":
            n = int(rng.integers(1, 40))
            rows = np.column_stack([rng.integers(0, sx, n), rng.integers(0, sy, n), rng.integers(0, sz, n),
                                    rng.integers(0, 256, n)]).astype(np.uint16)
            ops.append({"op": "voxels", "voxels": rows if blob else rows.tolist()})
        elif kind == "box":
            lo = [int(rng.integers(-4, s)) for s in size]
            hi = [v + int(rng.integers(0, 8)) for v in lo]
            ops.append({"op": "box", "min": lo, "max": hi, "colour": colour})
        else:
            center = [int(rng.integers(0, s)) for s in size]
            ops.append({"op": "sphere", "center": center, "radius": int(rng.integers(0, 6)) + 0.5,
                        "colour": colour})
    return ops


@pytest.fixture(scope="session")
def ref():
    """The references (tests/references.py) and the random batch, for test modules."""
    from types import SimpleNamespace

    return SimpleNamespace(apply=apply_reference, distance=distance_reference, batch=random_batch)
