"""An engine held by one long step: /readyz and /metrics say so, and requests cut off by a stop
get 503. Real server processes; the long step is a stand-in, a recompute that sleeps (injected
with a ``sitecustomize`` module, as tests/api/test_server.py does)."""

from __future__ import annotations

import signal
import threading
import time

import httpx
import pytest

from server_process import ServerProcess

from test_server import hooked

SLOW_S = 12.0  # longer than an API process's graceful stop (5 s)
WORLD = {"size": [16, 16, 16], "chunk_size": 8}
BOX = {"op": "box", "min": [1, 1, 1], "max": [4, 4, 4], "colour": 5}
# A world of max_distance 44 recomputes for SLOW_S seconds.
SLOW = f'''
import time
from sdfserver.world import World

_begin = World.begin_recompute


def begin_recompute(self, *args, **kwargs):
    if self.config.max_distance == 44:
        time.sleep({SLOW_S})
    return _begin(self, *args, **kwargs)


World.begin_recompute = begin_recompute
'''


@pytest.fixture
def slow_server(tmp_path):
    server = ServerProcess(tmp_path / "data", "--no-warm-up", "--workers", "2", env=hooked(tmp_path, SLOW))
    yield server.wait_ready()
    if server.process.poll() is None:
        server.stop()
    else:
        server.close()


def hold_the_engine(server: ServerProcess) -> str:
    """A world whose recompute, started now, holds the engine SLOW_S seconds; its id."""
    slow = httpx.post(server.url + "/v1/worlds", json={**WORLD, "max_distance": 44}).json()["id"]
    r = httpx.post(f"{server.url}/v1/worlds/{slow}/edits", json={"edits": [BOX]})
    assert r.status_code == 200  # acknowledged once logged, before its recompute
    return slow


def in_thread(fn) -> tuple[threading.Thread, list]:
    """``fn()`` on a thread; its answer, or what it raised, in the list."""
    out: list = []

    def run():
        try:
            out.append(fn())
        except Exception as exc:
            out.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread, out


def test_a_busy_engine_is_ready_and_says_what_holds_it(slow_server):
    slow = hold_the_engine(slow_server)
    time.sleep(0.5)
    r = httpx.get(slow_server.url + "/readyz", timeout=5)
    assert r.status_code == 200
    body = r.json()
    assert body["status"] == "ready"
    [busy] = body["busy"]
    assert busy["engine"] == 0 and busy["phase"] == "recompute" and busy["worlds"] == [slow]
    assert busy["busy_ms"] >= 400
    metrics = httpx.get(slow_server.url + "/metrics", timeout=5).text
    [line] = [x for x in metrics.splitlines() if x.startswith("sdfserver_engine_busy_seconds ")]
    assert float(line.split()[1]) >= 0.4
    # once the step is over, nothing is busy
    deadline = time.monotonic() + SLOW_S + 30
    while time.monotonic() < deadline and httpx.get(slow_server.url + "/readyz").json()["busy"]:
        time.sleep(0.5)
    assert httpx.get(slow_server.url + "/readyz").json()["busy"] == []
    metrics = httpx.get(slow_server.url + "/metrics", timeout=5).text
    assert "sdfserver_engine_busy_seconds 0.0" in metrics.splitlines()


def test_requests_cut_off_by_a_stop_get_503(slow_server):
    hold_the_engine(slow_server)
    waiting = [in_thread(lambda: httpx.get(slow_server.url + "/v1/worlds", timeout=60)) for _ in range(4)]
    time.sleep(1.0)  # the reads wait behind the long step
    assert all(t.is_alive() for t, _ in waiting)
    slow_server.process.send_signal(signal.SIGTERM)
    for thread, out in waiting:
        thread.join(30)
        assert not thread.is_alive()
        [r] = out
        assert isinstance(r, httpx.Response), r
        assert r.status_code == 503, r.text
        assert r.json()["error"]["code"] == "not_ready" and r.headers["retry-after"] == "1"
    slow_server.process.wait(60)
