"""The ``start_server`` fixture: servers over the test's own data directory, stopped at the end."""

from __future__ import annotations

from pathlib import Path

import pytest

from durable_server import ServerProcess


@pytest.fixture
def start_server(tmp_path):
    started: list[ServerProcess] = []

    def start(*flags: str, data_dir: Path | None = None, ready: bool = True, **kw) -> ServerProcess:
        server = ServerProcess(data_dir or tmp_path / "data", *flags, **kw)
        started.append(server)
        return server.wait_ready() if ready else server

    yield start
    for server in started:
        if server.process.poll() is None:
            server.stop()
        elif not server.log.closed:
            server.close()
