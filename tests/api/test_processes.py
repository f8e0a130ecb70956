"""The launcher's processes: several engines (``--devices``) with worlds routed by id, an API
process that dies is replaced, an engine process that dies ends the server with its cause."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import httpx

from server_process import ServerProcess

WORLD = {"size": [16, 16, 16], "chunk_size": 8, "max_distance": 6}
BOX = {"op": "box", "min": [1, 1, 1], "max": [4, 4, 4], "colour": 5}


def children(pid: int) -> list[int]:
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        out += [int(c) for c in (task / "children").read_text().split()]
    return out


def name_of(pid: int) -> str:
    return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()


def engine_and_api_pids(server: ServerProcess) -> tuple[list[int], list[int]]:
    """The engine processes answer on their ZeroMQ sockets, the API processes on the port: tell
    them apart by who listens on TCP (an API process holds the launcher's socket too, but only
    they have uvicorn's 'Started server process' line in the log)."""
    pids = children(server.process.pid)
    log = server.output()
    api = [pid for pid in pids if f"Started server process [{pid}]" in log]
    return [pid for pid in pids if pid not in api], api


def wait_for(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


def test_two_engines_hold_worlds_routed_by_id(tmp_path):
    server = ServerProcess(tmp_path / "data", "--no-warm-up", "--devices", "0,0", "--workers", "2",
                           "--memory-budget-bytes", str(64 << 20)).wait_ready()
    try:
        with httpx.Client(base_url=server.url, timeout=30) as http:
            assert len(http.get("/readyz").json()["devices"]) == 2
            ids = [http.post("/v1/worlds", json=WORLD).json()["id"] for _ in range(4)]
            for i, world_id in enumerate(ids):
                box = {**BOX, "colour": 10 + i}
                assert http.post(f"/v1/worlds/{world_id}/edits", json={"edits": [box]}).json() == {"version": 1}
            listed = {w["id"] for w in http.get("/v1/worlds").json()["worlds"]}
            assert listed == set(ids)
            metrics = http.get("/metrics").text.splitlines()
            assert metrics.count("# TYPE sdfserver_worlds gauge") == 1  # one family, a sample per engine
            worlds = {line.split()[0]: float(line.split()[1]) for line in metrics
                      if line.startswith("sdfserver_worlds{")}
            assert set(worlds) == {'sdfserver_worlds{engine="0"}', 'sdfserver_worlds{engine="1"}'}
            assert sum(worlds.values()) == 4
            for i, world_id in enumerate(ids):  # over fresh connections: any API process, any engine
                with httpx.Client(base_url=server.url, timeout=30) as fresh:
                    r = fresh.get(f"/v1/worlds/{world_id}/voxels", params={"min": "1,1,1", "max": "2,2,2"},
                                  headers={"accept": "application/json"})
                    assert r.status_code == 200 and r.json()["version"] == 1
        engines = [p for p in (tmp_path / "data").iterdir() if p.name.startswith("engine-")]
        assert sorted(p.name for p in engines) == ["engine-0", "engine-1"]
        assert all(any(e.iterdir()) for e in engines), "worlds go to both engines (most free memory first)"
    finally:
        server.stop()


def test_a_dead_api_process_is_replaced_and_a_dead_engine_ends_the_server(tmp_path):
    server = ServerProcess(tmp_path / "data", "--no-warm-up", "--workers", "2").wait_ready()
    try:
        wait_for(lambda: len(engine_and_api_pids(server)[1]) == 2, 30, "two API processes")
        engines, api = engine_and_api_pids(server)
        assert len(engines) == 1
        os.kill(api[0], signal.SIGKILL)
        wait_for(lambda: len(set(engine_and_api_pids(server)[1]) - set(api)) == 1, 30, "a new API process")
        for _ in range(20):  # served throughout by whichever API process takes the connection
            with httpx.Client(base_url=server.url, timeout=30) as http:
                assert http.get("/readyz").status_code == 200
        os.kill(engines[0], signal.SIGKILL)
        code = server.process.wait(60)
    finally:
        server.kill()
    output = server.output().strip().splitlines()
    assert code == 1, output[-5:]
    assert output[-1] == ("sdfserver serve: the engine process exited with status -9; exiting, so that a "
                          "supervisor can start it again"), output[-5:]


def test_a_stopped_api_process_leaves_new_connections_to_the_others_and_a_stopped_engine_is_not_ready(tmp_path):
    server = ServerProcess(tmp_path / "data", "--no-warm-up", "--workers", "2").wait_ready()
    try:
        wait_for(lambda: len(engine_and_api_pids(server)[1]) == 2, 30, "two API processes")
        engines, api = engine_and_api_pids(server)
        os.kill(api[0], signal.SIGSTOP)  # hangs: alive to the launcher, deaf to the socket
        try:
            for _ in range(20):  # each a new connection, accepted by the process that runs
                assert httpx.get(server.url + "/livez", timeout=5).status_code == 200
        finally:
            os.kill(api[0], signal.SIGCONT)
        os.kill(engines[0], signal.SIGSTOP)
        try:
            r = httpx.get(server.url + "/readyz", timeout=10)
            assert r.status_code == 503 and "did not answer" in r.json()["error"]["message"], r.text
        finally:
            os.kill(engines[0], signal.SIGCONT)
        assert httpx.get(server.url + "/readyz", timeout=10).status_code == 200
    finally:
        server.stop()
