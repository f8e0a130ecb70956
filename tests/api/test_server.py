"""``sdfserver serve`` starts and serves, or says why not and exits: an engine that cannot start,
a port already in use (with one API process or several), a step that raises, a device lost, an
engine thread that dies. Real server processes on loopback; faults are injected with a
``sitecustomize`` module put first on the server's PYTHONPATH (every process of the server runs
it; only the engine process runs what it patches)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import httpx
import pytest

from server_process import ServerProcess, checkout_env

EXIT_WITHIN_S = 60  # bounds a hang, not a speed
WORLD = {"size": [16, 16, 16], "chunk_size": 8}
BOX = {"op": "box", "min": [1, 1, 1], "max": [4, 4, 4], "colour": 5}

# A world's max_distance picks the fault: its recompute raises a bug (66) or an OpenCL error
# (77, a lost device); a world of 55 makes the engine thread's loop raise, outside any step.
FAULTS = '''
import pyopencl as cl
from sdfserver.engine.core import Engine
from sdfserver.world import World

_begin_recompute, _wait_timeout = World.begin_recompute, Engine._wait_timeout


def begin_recompute(self, *args, **kwargs):
    if self.config.max_distance == 66:
        raise RuntimeError("a simulated bug in a step")
    if self.config.max_distance == 77:
        raise cl.RuntimeError("simulated device loss")
    return _begin_recompute(self, *args, **kwargs)


def wait_timeout(self):
    if any(w.config.max_distance == 55 for w in self.worlds.values()):
        raise RuntimeError("a simulated bug outside a step")
    return _wait_timeout(self)


World.begin_recompute, Engine._wait_timeout = begin_recompute, wait_timeout
'''
FAILING_WARM_UP = '''
from sdfserver.engine import lifetime


def warm_up(gpu):
    raise RuntimeError("a simulated kernel build failure\\nwith a build log after it")


lifetime.warm_up = warm_up
'''


def hooked(tmp_path: Path, code: str) -> dict[str, str]:
    """The server's environment with ``code`` run at its interpreter's start."""
    hooks = tmp_path / "hooks"
    hooks.mkdir(exist_ok=True)
    (hooks / "sitecustomize.py").write_text(code)
    return checkout_env(hooks)


def exited(server: ServerProcess) -> tuple[int, str]:
    try:
        code = server.process.wait(EXIT_WITHIN_S)
    finally:
        server.kill()
    return code, server.output()


def last_line(output: str) -> str:
    return output.strip().splitlines()[-1]


def status_of(response: httpx.Response) -> tuple[int, str, str]:
    error = response.json()["error"]
    return response.status_code, error["code"], error["message"]


# -- an engine that cannot start ---------------------------------------------------------------------


def test_an_engine_whose_warm_up_fails_stops_the_server_with_the_reason(tmp_path):
    server = ServerProcess(tmp_path / "data", env=hooked(tmp_path, FAILING_WARM_UP))
    code, output = exited(server)
    line = last_line(output)
    assert code == 1, output
    assert line.startswith("sdfserver serve: the engine could not start on "), output
    assert "RuntimeError: a simulated kernel build failure; `sdfserver devices` lists" in line
    assert "--device" in line and "listening" not in output


def test_a_device_that_does_not_exist_stops_the_server_with_the_reason(tmp_path):
    code, output = exited(ServerProcess(tmp_path / "data", "--device", "no-such-device"))
    assert code == 1 and "No OpenCL device matches 'no-such-device'" in last_line(output), output
    assert "--device" in last_line(output) and "listening" not in output


# -- one server per port -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def faulty(tmp_path_factory):
    """A server with two API processes and the faults above; the device-loss test, last, ends its use."""
    tmp = tmp_path_factory.mktemp("faulty")
    server = ServerProcess(tmp / "data", "--no-warm-up", "--max-wait-ms", "60000",
                           env=hooked(tmp, FAULTS)).wait_ready()
    yield server
    server.stop()


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_second_server_on_a_port_in_use_stops(faulty, tmp_path, workers):
    second = ServerProcess(tmp_path / "data", "--workers", workers, port=faulty.port)
    code, output = exited(second)
    assert code == 1 and "address already in use" in last_line(output), output
    assert httpx.get(faulty.url + "/readyz").status_code == 200  # the first serves on


# -- failures while serving ------------------------------------------------------------------------


def engine_steps(server: ServerProcess) -> float:
    for line in httpx.get(server.url + "/metrics").text.splitlines():
        if line.startswith("sdfserver_engine_steps_total "):
            return float(line.split()[1])
    raise KeyError("sdfserver_engine_steps_total")


def waiting_read(server: ServerProcess, world_id: str, min_version: int) -> tuple[threading.Thread, list]:
    """A field read of a version not there yet, returned once the engine holds it waiting."""
    answer: list[httpx.Response] = []
    before = engine_steps(server)
    reader = threading.Thread(target=lambda: answer.append(httpx.get(
        f"{server.url}/v1/worlds/{world_id}/field", params={"min_version": min_version}, timeout=EXIT_WITHIN_S)))
    reader.start()
    deadline = time.monotonic() + EXIT_WITHIN_S
    while engine_steps(server) == before and time.monotonic() < deadline:
        time.sleep(0.02)
    return reader, answer


def test_a_step_that_raises_fails_its_requests_and_the_server_goes_on(faulty):
    buggy = httpx.post(faulty.url + "/v1/worlds", json={**WORLD, "max_distance": 66}).json()["id"]
    healthy = httpx.post(faulty.url + "/v1/worlds", json={**WORLD, "max_distance": 6}).json()["id"]
    reader, answer = waiting_read(faulty, buggy, 1)  # served in the step whose recompute raises
    r = httpx.post(f"{faulty.url}/v1/worlds/{buggy}/edits", json={"edits": [BOX]})
    assert r.status_code == 200 and r.json()["version"] == 1  # applied and logged before the recompute
    reader.join(EXIT_WITHIN_S)
    assert status_of(answer[0]) == (500, "internal_error", "internal error in an engine step: RuntimeError: "
                                                           "a simulated bug in a step")
    r = httpx.post(f"{faulty.url}/v1/worlds/{healthy}/edits", json={"edits": [BOX]})
    assert r.status_code == 200 and r.json()["version"] == 1
    assert httpx.get(f"{faulty.url}/v1/worlds/{healthy}/field", params={"min_version": 1}).status_code == 200
    assert httpx.get(faulty.url + "/readyz").status_code == 200


def test_after_a_device_loss_every_request_answers_503_at_once(faulty):
    healthy = httpx.post(faulty.url + "/v1/worlds", json={**WORLD, "max_distance": 6}).json()["id"]
    lost = httpx.post(faulty.url + "/v1/worlds", json={**WORLD, "max_distance": 77}).json()["id"]
    reader, answer = waiting_read(faulty, healthy, 99)  # would wait 60 s for a version that never comes
    r = httpx.post(f"{faulty.url}/v1/worlds/{lost}/edits", json={"edits": [BOX]})
    assert r.status_code == 200  # applied and logged before the device failed in its recompute
    cause = "device error: simulated device loss"
    reader.join(20)  # far less than the read's own 60 s
    assert not reader.is_alive() and status_of(answer[0]) == (503, "not_ready", cause)
    assert status_of(httpx.get(faulty.url + "/readyz")) == (503, "not_ready", cause)
    for request in (httpx.Request("GET", faulty.url + "/v1/worlds"),
                    httpx.Request("POST", faulty.url + "/v1/worlds", json=WORLD),
                    httpx.Request("GET", f"{faulty.url}/v1/worlds/{healthy}"),
                    httpx.Request("POST", f"{faulty.url}/v1/worlds/{healthy}/edits", json={"edits": [BOX]}),
                    httpx.Request("GET", f"{faulty.url}/v1/worlds/{healthy}/field")):
        with httpx.Client(timeout=10) as client:  # a hang fails here, not at the suite's timeout
            assert status_of(client.send(request)) == (503, "not_ready", cause), request
    assert faulty.process.poll() is None  # up, saying why it cannot serve


def test_a_dead_engine_thread_stops_the_server(tmp_path):
    """And one with a single API process holds its port as well."""
    server = ServerProcess(tmp_path / "data", "--no-warm-up", "--workers", "1",
                           env=hooked(tmp_path, FAULTS)).wait_ready()
    try:
        second = ServerProcess(tmp_path / "second", port=server.port)
        code, output = exited(second)
        assert code == 1 and "address already in use" in last_line(output), output
        r = httpx.post(server.url + "/v1/worlds", json={**WORLD, "max_distance": 55})
        assert r.status_code == 201
        code, output = exited(server)
    finally:
        server.kill()
    assert code == 1, output
    assert last_line(output) == ("sdfserver serve: the engine thread died: RuntimeError: a simulated bug "
                                 "outside a step; exiting, so that a supervisor can start it again")

