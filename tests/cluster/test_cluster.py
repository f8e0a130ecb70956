"""`sdfserver serve --cluster local`: engines as Ray actors on a local Ray cluster (one per
module), on the CPU device; a real server on loopback, its engine actors killed under load,
every link to them proven with the engines' credentials (engine/links.py), which a peer
without them cannot pass."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from references import apply_edits, oracle_distance
from sdfserver.engine import frames
from sdfserver.engine import messages as msg
from server_process import ServerProcess

pytest.importorskip("ray")
SIZE = (24, 16, 24)
CAP = 12
KILLS = 50
FLAGS = ["--cluster", "local", "--engines", "2", "--engine-gpus", "0", "--workers", "1", "--no-warm-up",
         "--memory-budget-bytes", str(64 << 20)]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("cluster") / "data", *FLAGS)
    try:
        yield process.wait_ready(timeout_s=240)
    finally:
        process.stop(timeout_s=60)


def engines(server) -> list[dict]:
    r = httpx.get(server.url + "/v1/engines", timeout=30)
    assert r.status_code == 200, r.text
    return r.json()


def new_world(server) -> str:
    r = httpx.post(server.url + "/v1/worlds", json={"size": list(SIZE), "chunk_size": 8, "max_distance": CAP},
                   timeout=30)
    assert r.status_code == 201, r.text
    return r.json()["id"]


def random_batch(rng: np.random.Generator) -> list[dict]:
    ops = []
    for _ in range(int(rng.integers(1, 3))):
        colour = int(rng.integers(0, 256)) if rng.random() < 0.7 else 0  # some remove voxels
        if rng.random() < 0.5:
            lo = [int(rng.integers(-2, s)) for s in SIZE]
            ops.append({"op": "box", "min": lo, "max": [v + int(rng.integers(1, 7)) for v in lo], "colour": colour})
        else:
            ops.append({"op": "sphere", "center": [float(rng.uniform(0, s)) for s in SIZE],
                        "radius": float(rng.uniform(1, 5)), "colour": colour})
    return ops


def read(server, world: str, what: str) -> np.ndarray:
    r = httpx.get(f"{server.url}/v1/worlds/{world}/{what}", headers={"accept": "application/octet-stream"},
                  timeout=30)
    assert r.status_code == 200, r.text
    shape = tuple(int(v) for v in r.headers["x-sdf-shape"].split(","))
    return np.frombuffer(r.content, np.uint8).reshape(shape)


def test_the_embedded_server_never_imports_ray():
    code = ("import sys, sdfserver, sdfserver.api.server, sdfserver.api.app, sdfserver.api.worker, "
            "sdfserver.engine.proc; assert 'ray' not in sys.modules, 'ray imported'")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_worlds_spread_over_the_engine_actors_and_say_where_they_are(server):
    worlds = [new_world(server) for _ in range(4)]
    listed = engines(server)
    assert [e["engine"] for e in listed] == [0, 1]
    assert all(e["ready"] and e["address"].startswith("tcp://") for e in listed)
    assert len({e["pid"] for e in listed} | {server.process.pid}) == 3  # actors, not the launcher
    holders = {w: e["engine"] for e in listed for w in e["world_ids"]}
    for world in worlds:
        described = httpx.get(f"{server.url}/v1/worlds/{world}", timeout=30).json()
        assert described["engine"] == holders[world]
    assert {holders[w] for w in worlds} == {0, 1}  # new worlds go where most memory is free


def refused_links(server, reason: str) -> float:
    """sdfserver_engine_links_refused_total{reason} summed over the engines, from /metrics."""
    r = httpx.get(server.url + "/metrics", timeout=30)
    assert r.status_code == 200, r.text
    return sum(sample.value for family in text_string_to_metric_families(r.text) for sample in family.samples
               if sample.name == "sdfserver_engine_links_refused_total" and sample.labels["reason"] == reason)


def test_a_forged_admin_delete_on_an_engine_actors_port_changes_nothing_and_is_counted(server):
    """What a hostile peer on the engine's network sends: an identity and a DeleteWorld claiming
    admin, with no proof. The engine closes the connection without reading the request."""
    world = new_world(server)
    holder = next(e for e in engines(server) if world in e["world_ids"])
    before = refused_links(server, "credential")
    _, target = frames.family_and_target(holder["address"])
    forged = msg.REQUEST_ENCODER.encode(msg.DeleteWorld(1, world, msg.Access(None, True, "10.6.6.6")))
    with socket.create_connection(target, timeout=10) as forger:
        forger.sendall(frames.frame(b"api-forger") + frames.frame(forged))
        closed = False
        try:
            while forger.recv(1 << 16):
                pass
            closed = True
        except ConnectionResetError:
            closed = True
        except TimeoutError:
            pass
    time.sleep(0.5)  # a delete that got through would have been applied by now
    assert httpx.get(f"{server.url}/v1/worlds/{world}", timeout=30).status_code == 200, "the forged delete was applied"
    assert closed, "the engine kept a connection that proved nothing"
    assert refused_links(server, "credential") == before + 1


def test_engine_actors_listen_only_on_the_address_they_advertise(server):
    """127.0.0.1 on a local cluster, not every interface (/proc/net/tcp: each listening socket's
    local address, hex, little-endian)."""
    listening = {}
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        if state == "0A":
            address, port = local.split(":")
            listening[int(port, 16)] = address
    for engine in engines(server):
        port = int(engine["address"].rsplit(":", 1)[1])
        assert engine["address"].startswith("tcp://127.0.0.1:")
        assert listening.get(port) == "0100007F", f"engine {engine['engine']} listens on {listening.get(port)}"


def test_a_killed_engine_actor_comes_back_with_every_acknowledged_batch(server):
    rng = np.random.default_rng()
    worlds = [new_world(server) for _ in range(2)]
    listed = engines(server)
    victim = next(e for e in listed if worlds[0] in e["world_ids"])
    acked: dict[str, list[list[dict]]] = {w: [] for w in worlds}
    killed = threading.Event()
    stop = threading.Event()
    errors: list[str] = []

    def writer(world: str, seed: int) -> None:
        batches = np.random.default_rng(seed)
        with httpx.Client(base_url=server.url, timeout=30) as http:
            while not stop.is_set():
                batch = random_batch(batches)
                key = {"idempotency-key": f"{world}-{len(acked[world])}-{batches.integers(1 << 60)}"}
                for attempt in range(100):  # an unanswered attempt may have been applied: its id
                    try:                    # makes the retry answer it rather than apply it again
                        r = http.post(f"/v1/worlds/{world}/edits", json={"edits": batch}, headers=key)
                    except httpx.TransportError as exc:
                        errors.append(type(exc).__name__)
                        time.sleep(0.1)
                        continue
                    if r.status_code == 200:
                        acked[world].append(batch)
                        break
                    errors.append(f"{r.status_code} {r.text[:80]}")
                    assert r.status_code == 503, r.text
                    time.sleep(0.1)

    threads = [threading.Thread(target=writer, args=(w, int(rng.integers(1 << 30)))) for w in worlds]
    for t in threads:
        t.start()
    pids = [victim["pid"]]
    try:
        for _ in range(KILLS):  # each time the engine holding the first world, mid-write
            before = len(acked[worlds[0]])
            deadline = time.monotonic() + 60
            while len(acked[worlds[0]]) < before + 5 and time.monotonic() < deadline:
                time.sleep(0.05)
            os.kill(pids[-1], signal.SIGKILL)
            killed_at, before = time.monotonic(), len(acked[worlds[0]])
            while len(acked[worlds[0]]) < before + 5 and time.monotonic() < killed_at + 120:
                time.sleep(0.05)
            back_after_s = time.monotonic() - killed_at
            assert len(acked[worlds[0]]) >= before + 5, f"not serving again in {back_after_s:.1f} s: {errors}"
            restarted = next(e for e in engines(server) if e["engine"] == victim["engine"])
            assert restarted["pid"] not in pids and worlds[0] in restarted["world_ids"]
            pids.append(restarted["pid"])
    finally:
        stop.set()
        for t in threads:
            t.join(timeout=120)
    for world in worlds:
        version = httpx.get(f"{server.url}/v1/worlds/{world}", timeout=30).json()["version"]
        assert version == len(acked[world]), "a retried batch was applied twice"
        expected = np.zeros(SIZE[::-1], np.uint8)
        for batch in acked[world]:
            apply_edits(expected, batch)
        np.testing.assert_array_equal(read(server, world, "voxels"), expected)
        np.testing.assert_array_equal(read(server, world, "field"), oracle_distance(expected, CAP))


def test_a_world_moves_between_engine_actors_under_a_writer_losing_and_doubling_nothing(server):
    world = new_world(server)
    acked: list[list[dict]] = []
    stop = threading.Event()

    def writer(seed: int) -> None:
        batches = np.random.default_rng(seed)
        with httpx.Client(base_url=server.url, timeout=30) as http:
            while not stop.is_set():
                batch, key = random_batch(batches), {"idempotency-key": f"move-{len(acked)}-{batches.integers(1 << 60)}"}
                for _ in range(100):
                    r = http.post(f"/v1/worlds/{world}/edits", json={"edits": batch}, headers=key)
                    if r.status_code == 200:
                        acked.append(batch)
                        break
                    assert r.status_code == 503, r.text
                    time.sleep(0.05)

    thread = threading.Thread(target=writer, args=(int(np.random.default_rng().integers(1 << 30)),))
    thread.start()
    try:
        here = httpx.get(f"{server.url}/v1/worlds/{world}", timeout=30).json()["engine"]
        for _ in range(3):
            time.sleep(0.3)
            r = httpx.post(f"{server.url}/v1/worlds/{world}/move", json={"engine": 1 - here}, timeout=60)
            assert r.status_code == 200 and r.json()["engine"] == 1 - here, r.text
            here = 1 - here
            assert world in next(e for e in engines(server) if e["engine"] == here)["world_ids"]
    finally:
        stop.set()
        thread.join(timeout=60)
    assert httpx.get(f"{server.url}/v1/worlds/{world}", timeout=30).json()["version"] == len(acked) > 5
    expected = np.zeros(SIZE[::-1], np.uint8)
    for batch in acked:
        apply_edits(expected, batch)
    np.testing.assert_array_equal(read(server, world, "field"), oracle_distance(expected, CAP))


def test_an_engine_restarted_at_another_address_is_followed(server):
    """As after a restart on another node: the actor's ports are taken when Ray restarts it, so
    it listens elsewhere; the API processes follow the address the cluster process publishes."""
    import socket

    world = new_world(server)
    batch = [{"op": "box", "min": [2, 2, 2], "max": [9, 9, 9], "colour": 77}]
    assert httpx.post(f"{server.url}/v1/worlds/{world}/edits", json={"edits": batch}, timeout=30).status_code == 200
    victim = next(e for e in engines(server) if world in e["world_ids"])
    port = int(victim["address"].rsplit(":", 1)[1])
    os.kill(victim["pid"], signal.SIGKILL)
    blocker = socket.socket()
    blocker.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # its connections linger in TIME_WAIT
    deadline = time.monotonic() + 10
    while True:  # the dead process's listening socket is gone at once
        try:
            blocker.bind(("", port))
            blocker.listen()
            break
        except OSError:
            assert time.monotonic() < deadline, f"port {port} stayed taken"
            time.sleep(0.02)
    try:
        second = [{"op": "sphere", "center": [16.0, 8.0, 16.0], "radius": 3.0, "colour": 5}]
        deadline = time.monotonic() + 120
        while True:
            try:
                r = httpx.post(f"{server.url}/v1/worlds/{world}/edits", json={"edits": second}, timeout=30,
                               headers={"idempotency-key": f"follow-{world}"})
                if r.status_code == 200:
                    break
                assert r.status_code == 503, r.text
            except httpx.TransportError:
                pass
            assert time.monotonic() < deadline, "the restarted engine was not reached at its new address"
            time.sleep(0.2)
        moved = next(e for e in engines(server) if e["engine"] == victim["engine"])
        assert moved["address"] != victim["address"] and moved["pid"] != victim["pid"], moved
        assert r.json()["version"] == 2
        expected = np.zeros(SIZE[::-1], np.uint8)
        for b in (batch, second):
            apply_edits(expected, b)
        np.testing.assert_array_equal(read(server, world, "field"), oracle_distance(expected, CAP))
    finally:
        blocker.close()


def test_engines_asking_for_gpus_the_cluster_lacks_stop_the_server_with_why(tmp_path):
    process = ServerProcess(tmp_path / "data", "--cluster", "local", "--engines", "2", "--engine-gpus", "8",
                            "--no-warm-up")
    try:
        assert process.process.wait(timeout=120) == 1
        assert "2 engines x 8 GPUs need 16 GPUs; the Ray cluster has" in process.output()
    finally:
        process.stop()
