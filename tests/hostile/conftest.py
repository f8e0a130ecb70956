"""Servers of the hostile-client tests, each over its own data directory, stopped at the end."""

from __future__ import annotations

import pytest

from hostile_server import HostileServer


@pytest.fixture
def start_server(tmp_path):
    started: list[HostileServer] = []

    def start(*flags: str, data_dir=None, hooks: str | None = None, ready: bool = True) -> HostileServer:
        server = HostileServer(data_dir or tmp_path / "data", *flags, hooks=hooks)
        started.append(server)
        return server.wait_ready() if ready else server

    yield start
    for server in started:
        if server.process.poll() is None:
            server.stop()
        elif not server.log.closed:
            server.close()
