"""Real `sdfserver serve` processes on loopback for the web tests: an open one shared by the
whole directory, and one that requires API keys.

Each server gets a data directory of its own: worlds are durable, so a shared directory would
hand one server the worlds another test left behind (and the demo would open one of those
instead of making its own scene).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import pytest

from server_process import ServerProcess

# name:token pairs for the keyed server (tokens are 16+ characters).
KEYS = {"painter": "painter-token-0123456789", "other": "other-token-0123456789ab"}


@contextlib.contextmanager
def serve(data_dir: Path, *flags: str):
    server = ServerProcess(data_dir, *flags).wait_ready()
    try:
        yield server.url, server.log_path
    finally:
        server.stop()
        print(f"server log: {server.log_path}")


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
