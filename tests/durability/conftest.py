"""The ``start_server`` fixture: servers over the test's own data directory, stopped at the end."""

from __future__ import annotations

import pytest

from durable_server import ServerProcess
from server_process import server_starter


@pytest.fixture
def start_server(tmp_path):
    yield from server_starter(ServerProcess, tmp_path)
