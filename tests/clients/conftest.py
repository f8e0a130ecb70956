"""A real ``sdfserver serve`` process on loopback, one per test module."""

from __future__ import annotations

import subprocess
import sys
import time

import httpx
import pytest

from clients_support import CLIENTS, ROOT, env_with_paths, free_port  # noqa: F401

READY_TIMEOUT_S = 120.0  # PoCL builds the kernels while the server warms up


@pytest.fixture(scope="module")
def server_url(tmp_path_factory):
    port = free_port()
    home = tmp_path_factory.mktemp("server")
    log_path = home / "server.log"
    log = open(log_path, "wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "sdfserver", "serve", "--host", "127.0.0.1", "--port", str(port),
         "--data-dir", str(home / "data")],  # its own: worlds are durable
        cwd=ROOT, env=env_with_paths(), stdout=log, stderr=subprocess.STDOUT,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + READY_TIMEOUT_S
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"sdfserver serve exited with {proc.returncode}:\n{log_path.read_text()}")
            try:
                if httpx.get(url + "/readyz", timeout=1.0).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError(f"sdfserver serve not ready in {READY_TIMEOUT_S:g} s:\n{log_path.read_text()}")
            time.sleep(0.2)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()
