"""clients/loadtest: brushes from a seed, and short runs against a real server."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
from clients_support import CLIENTS, ROOT, env_with_paths

from sdfclient import Client

sys.path.insert(0, str(CLIENTS))
import loadtest  # noqa: E402


def _config(**kw) -> loadtest.LoadConfig:
    return loadtest.LoadConfig(url="http://unused", world_size=(48, 32, 16), **kw)


def test_brushes_are_seeded_and_inside_the_world():
    cfg = _config(delete_fraction=0.3, sphere_fraction=0.5, brush_min=2, brush_max=6, ops_per_batch=3)
    first = [loadtest.Brushes(11, cfg).batch() for _ in range(1)]
    a, b, c = loadtest.Brushes(11, cfg), loadtest.Brushes(11, cfg), loadtest.Brushes(12, cfg)
    batches_a = [a.batch() for _ in range(400)]
    assert batches_a == [b.batch() for _ in range(400)] and batches_a[0] == first[0]
    assert batches_a != [c.batch() for _ in range(400)]
    ops = [op for batch, _ in batches_a for op in batch]
    assert all(len(batch) == 3 for batch, _ in batches_a)
    spheres = [op for op in ops if op["op"] == "sphere"]
    boxes = [op for op in ops if op["op"] == "box"]
    assert 0.4 < len(spheres) / len(ops) < 0.6 and len(spheres) + len(boxes) == len(ops)
    assert 0.2 < sum(op["colour"] == 0 for op in ops) / len(ops) < 0.4
    assert all(2 <= op["radius"] <= 6 for op in spheres)
    size = np.array(cfg.world_size)
    for op in spheres:
        assert (np.array(op["center"]) >= 0).all() and (np.array(op["center"]) < size).all()
    for op in boxes:
        lo, hi = np.array(op["min"]), np.array(op["max"])
        assert (lo >= 0).all() and (hi <= size).all() and (lo < hi).all()
    for _, centre in batches_a:
        box = a.read_box(centre)
        lo, hi = np.array(box[0]), np.array(box[1])
        assert (lo >= 0).all() and (hi <= size).all() and ((hi - lo) == np.minimum(16, size)).all()


def test_latency_summary():
    import array

    samples = array.array("d", np.random.default_rng().permutation(np.arange(1.0, 101.0)))
    summary = loadtest.latency_summary(samples, 2.0)
    assert summary["count"] == 100 and summary["throughput_per_s"] == 50.0
    lat = summary["latency_ms"]
    assert lat["min"] == 1.0 and lat["max"] == 100.0 and abs(lat["p50"] - 50.5) < 1e-9
    assert lat["p50"] < lat["p95"] < lat["p99"] <= lat["max"]


def _run(server_url: str, tmp_path, *args: str) -> tuple[subprocess.CompletedProcess, dict]:
    out = tmp_path / "result.json"
    proc = subprocess.run(
        [sys.executable, str(CLIENTS / "loadtest"), "--url", server_url, "--json", str(out), *args],
        cwd=ROOT, env=env_with_paths(), capture_output=True, timeout=120,
    )
    proc.stdout, proc.stderr = proc.stdout.decode(), proc.stderr.decode()  # keep the \r of the progress line
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc, json.loads(out.read_text())


def _check_client_cpu(result: dict, stdout: str, processes: int) -> None:
    """The load generator's CPU per request: positive, and no more than its processes could spend."""
    cpu_us = result["client_cpu_us_per_request"]
    assert 0 < cpu_us * result["requests"] / 1e6 <= result["elapsed_s"] * processes + 0.5
    assert f"load generator CPU {cpu_us:.0f} us/request ({result['config']['http']} HTTP client on " \
        f"{result['config']['loop']})" in stdout
    # Each process froze what it held before the run (tens of thousands of objects), so that its
    # own full collections, counted here, are short and are not the server's latency.
    collector = result["client_gc"]
    assert collector["frozen_objects"] > 10_000 * processes
    assert collector["full_collections"] >= 0 and 0 <= collector["longest_full_collection_ms"] < 1_000
    assert f"load generator's full collections: {collector['full_collections']}" in stdout


def test_short_run_reports_sane_numbers(server_url, tmp_path):
    proc, result = _run(server_url, tmp_path, "--clients", "4", "--duration", "2", "--size", "32", "32", "32")
    assert result["errors"] == {"count": 0, "by_code": {}, "first_message": {}}
    assert result["schedule"] == {"loop": "closed", "latency_from": "send"} and "closed loop" in proc.stdout
    edits, reads = result["edits"], result["reads"]
    assert edits["count"] > 0 and reads["count"] > 0
    assert abs(edits["count"] - reads["count"]) <= 4  # --read-every 1: one read per edit
    assert result["requests"] == edits["count"] + reads["count"]
    assert 1.5 < result["elapsed_s"] < 10
    assert abs(result["throughput_rps"] - result["requests"] / result["elapsed_s"]) < 1e-6
    for kind in (edits, reads):
        lat = kind["latency_ms"]
        assert 0 < lat["min"] <= lat["p50"] <= lat["p95"] <= lat["p99"] <= lat["max"] < 10_000
    trips = result["round_trips"]  # each read with the latency of the edit before it
    assert trips["count"] == reads["count"]
    assert trips["latency_ms"]["min"] >= reads["latency_ms"]["min"] + edits["latency_ms"]["min"] - 1e-9
    assert trips["latency_ms"]["max"] <= reads["latency_ms"]["max"] + edits["latency_ms"]["max"] + 1e-9
    assert "requests/s" in proc.stdout and "p99" in proc.stdout and "edit+read" in proc.stdout
    assert result["config"]["http"] == "httptools" and result["config"]["loop"] == "uvloop"  # installed here
    timeline = result["edit_timeline"]  # each second's edits and their p99
    seconds = [t["second"] for t in timeline]
    assert seconds == sorted(set(seconds)) and 0 <= seconds[0] and seconds[-1] <= result["elapsed_s"]
    assert sum(t["edits"] for t in timeline) == edits["count"]
    assert all(edits["latency_ms"]["min"] <= t["p99_ms"] <= edits["latency_ms"]["max"] for t in timeline)
    _check_client_cpu(result, proc.stdout, processes=1)
    assert proc.stderr.startswith("\r") and "requests" in proc.stderr  # the progress line
    with Client(server_url) as client:  # the world made for the run is gone
        assert result["world"]["id"] not in [w.id for w in client.list_worlds()]


def test_request_count_and_rate_bound_the_run_on_a_given_world(server_url, tmp_path):
    with Client(server_url) as client:
        world = client.create_world((32, 32, 32), chunk_size=16, max_distance=16)
        try:
            proc, result = _run(server_url, tmp_path, "--world", world.id, "--clients", "2", "--requests", "30",
                                "--read-every", "0", "--processes", "2", "--quiet", "--seed", "5")
            assert result["requests"] == 30 and result["edits"]["count"] == 30 and result["reads"]["count"] == 0
            assert client.get_world(world.id).version == 30
            _check_client_cpu(result, proc.stdout, processes=2)  # summed over the workers

            proc, result = _run(server_url, tmp_path, "--world", world.id, "--clients", "2", "--rate", "20",
                                "--duration", "1", "--read-every", "0", "--processes", "2", "--quiet")
            assert 10 <= result["requests"] <= 24 and result["errors"]["count"] == 0
            schedule = result["schedule"]  # an open loop, its send lags merged over both workers
            assert schedule["loop"] == "open" and schedule["sent"] == result["requests"]
            assert 0 <= schedule["missed"] <= schedule["sent"] and schedule["unsent_at_end"] >= 0
            service, latency = result["edits"]["service_time_ms"], result["edits"]["latency_ms"]
            assert latency["max"] >= service["max"] - 1e-6 and "open loop at 20/s" in proc.stdout
            version = 30 + result["edits"]["count"]
            assert client.get_world(world.id).version == version

            _, result = _run(server_url, tmp_path, "--world", world.id, "--clients", "2", "--requests", "20",
                             "--edits-over", "ws", "--quiet")
            # Each client alternates edit and read from one shared budget of 20 tickets, so
            # which client takes the last ticket decides whether edits are 10 or 11.
            edits, reads = result["edits"]["count"], result["reads"]["count"]
            assert edits + reads == 20 and edits in (10, 11)
            assert result["errors"]["count"] == 0 and result["config"]["edits_over"] == "ws"
            assert client.get_world(world.id).version == version + edits
            version += edits

            proc, result = _run(server_url, tmp_path, "--world", world.id, "--clients", "2", "--requests", "20",
                                "--http", "httpx", "--loop", "asyncio", "--quiet")
            edits, reads = result["edits"]["count"], result["reads"]["count"]
            assert edits + reads == 20 and edits in (10, 11) and result["errors"]["count"] == 0
            assert (result["config"]["http"], result["config"]["loop"]) == ("httpx", "asyncio")
            assert client.get_world(world.id).version == version + edits
            _check_client_cpu(result, proc.stdout, processes=1)
        finally:
            client.delete_world(world.id)


def test_unreachable_server_fails_fast(tmp_path):
    from clients_support import free_port

    proc = subprocess.run(
        [sys.executable, str(CLIENTS / "loadtest"), "--url", f"http://127.0.0.1:{free_port()}",
         "--duration", "1", "--timeout", "2"],
        cwd=ROOT, env=env_with_paths(), capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 2 and "cannot create the world" in proc.stderr
