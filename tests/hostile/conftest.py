"""Servers of the hostile-client tests, each over its own data directory, stopped at the end."""

from __future__ import annotations

import pytest

from hostile_server import HostileServer
from server_process import server_starter


@pytest.fixture
def start_server(tmp_path):
    yield from server_starter(HostileServer, tmp_path)
