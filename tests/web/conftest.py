"""Real `sdfserver serve` processes on loopback for the web tests: an open one shared by the
whole directory, and one that requires API keys.

Each server gets a data directory of its own: worlds are durable, so a shared directory would
hand one server the worlds another test left behind (and the demo would open one of those
instead of making its own scene).
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[2]
# name:token pairs for the keyed server (tokens are 16+ characters).
KEYS = {"painter": "painter-token-0123456789", "other": "other-token-0123456789ab"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(data_dir: Path, *flags: str):
    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("SDFSERVER_API_KEYS", None)
    env.pop("SDFSERVER_API_KEY_FILE", None)
    log_path = data_dir.parent / f"serve-{port}.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen([sys.executable, "-m", "sdfserver", "serve", "--port", str(port),
                                 "--data-dir", str(data_dir), *flags],
                                cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
        base = f"http://127.0.0.1:{port}"
        try:
            deadline = time.monotonic() + 60
            while True:
                try:
                    if httpx.get(base + "/readyz", timeout=1).status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"server did not start: {log_path.read_text()[-2000:]}")
                time.sleep(0.2)
            yield base, log_path
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            print(f"server log: {log_path}")


@pytest.fixture(scope="session")
def server(tmp_path_factory):
    with serve(tmp_path_factory.mktemp("web-server") / "data") as (base, _):
        yield base


@dataclass
class KeyedServer:
    url: str
    log: Path


@pytest.fixture(scope="module")
def keyed_server(tmp_path_factory):
    keys = ",".join(f"{name}:{token}" for name, token in KEYS.items())
    with serve(tmp_path_factory.mktemp("web-keyed-server") / "data", "--api-keys", keys) as (base, log):
        yield KeyedServer(base, log)
