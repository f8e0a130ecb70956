"""A real ``sdfserver serve`` process on loopback, one per test module, its data in a tmp dir."""

from __future__ import annotations

import pytest

from clients_support import serve


@pytest.fixture(scope="module")
def server_url(tmp_path_factory):
    """An open server (no API keys)."""
    with serve(tmp_path_factory.mktemp("server")) as url:
        yield url
