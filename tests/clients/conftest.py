"""A real ``sdfserver serve`` process on loopback, its data in a tmp dir: one open server shared by
the client tests (each makes and deletes its own worlds); test_client_auth.py starts a keyed one."""

from __future__ import annotations

import pytest

from clients_support import serve


@pytest.fixture(scope="session")
def server_url(tmp_path_factory):
    """An open server (no API keys)."""
    with serve(tmp_path_factory.mktemp("server")) as url:
        yield url
