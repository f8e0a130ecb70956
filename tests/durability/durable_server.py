"""Helpers of the durability tests: real `sdfserver serve` processes over a data directory the
test owns (started, killed with SIGKILL, restarted), and a NumPy reference of the box and
voxels edits the tests send."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
FLAGS = ["--memory-budget-bytes", str(32 << 20), "--no-warm-up", "--max-request-bytes", str(1 << 20),
         "--max-ops-per-batch", "64", "--max-brush-radius-vox", "40", "--max-wait-ms", "3000"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    def __init__(self, data_dir: Path, *flags: str, token: str | None = None, env: dict | None = None):
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log_path = data_dir.parent / f"server-{self.port}.log"
        self.log = open(self.log_path, "wb")
        full_env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
        full_env.pop("SDFSERVER_PORT", None)
        self.process = subprocess.Popen(
            [sys.executable, "-m", "sdfserver", "serve", "--host", "127.0.0.1", "--port", str(self.port),
             "--data-dir", str(data_dir), *FLAGS, *flags],
            cwd=ROOT, env=full_env, stdout=self.log, stderr=subprocess.STDOUT)
        headers = {"authorization": f"Bearer {token}"} if token else {}
        self.http = httpx.Client(base_url=self.url, timeout=30, headers=headers)

    def wait_ready(self, timeout_s: float = 120) -> "ServerProcess":
        deadline = time.monotonic() + timeout_s
        while True:
            if self.process.poll() is not None:
                raise RuntimeError(f"server exited {self.process.returncode}: {self.output()}")
            try:
                if httpx.get(self.url + "/readyz", timeout=2).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                self.kill()
                raise RuntimeError(f"server did not become ready: {self.output()}")
            time.sleep(0.05)

    def output(self) -> str:
        self.log.flush()
        return self.log_path.read_text(errors="replace")[-4000:]

    def kill(self) -> None:
        if self.process.poll() is None:
            os.kill(self.process.pid, signal.SIGKILL)
        self.process.wait()
        self.close()

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(15)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.close()

    def close(self) -> None:
        self.http.close()
        self.log.close()


def apply_reference(voxels: np.ndarray, edits: list[dict]) -> None:
    """Box and voxels edits on a (z, y, x) array, as the server defines them."""
    sz, sy, sx = voxels.shape
    for op in edits:
        if op["op"] == "voxels":
            rows = np.asarray(op["voxels"], dtype=np.int64).reshape(-1, 4)
            voxels[rows[:, 2], rows[:, 1], rows[:, 0]] = rows[:, 3]  # the tests send no duplicates
        else:
            lo = np.clip(op["min"], 0, (sx, sy, sz))
            hi = np.clip(op["max"], 0, (sx, sy, sz))
            voxels[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]] = op["colour"]


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
