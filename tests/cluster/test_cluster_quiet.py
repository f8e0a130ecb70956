"""What `sdfserver serve --cluster local` says: on a cluster without GPUs it runs CPU engines
unasked (and says so); an engine actor killed while a client writes is said once, plainly, and
the messages nobody waited for are summed in one line; a clean stop exits 0 with no stack dump."""

from __future__ import annotations

import os
import signal
import threading
import time

import httpx
import pytest

from server_process import ServerProcess

pytest.importorskip("ray")
# no --engine-gpus: the default is what is tested; CUDA_VISIBLE_DEVICES="" shows Ray no GPU on any host
FLAGS = ["--cluster", "local", "--engines", "2", "--workers", "1", "--no-warm-up",
         "--memory-budget-bytes", str(64 << 20)]


def test_a_cluster_without_gpus_serves_on_cpu_engines_says_a_restart_once_and_stops_quietly(tmp_path):
    server = ServerProcess(tmp_path / "data", *FLAGS, env={"CUDA_VISIBLE_DEVICES": ""})
    stop = threading.Event()
    try:
        server.wait_ready(timeout_s=240)
        world = httpx.post(f"{server.url}/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8},
                           timeout=30).json()["id"]
        victim = next(e for e in httpx.get(f"{server.url}/v1/engines", timeout=30).json()
                      if world in e["world_ids"])
        written: list[int] = []

        def writer() -> None:  # answers sent make the API process report its bytes every 0.5 s
            with httpx.Client(base_url=server.url, timeout=30) as http:
                while not stop.is_set():
                    r = http.post(f"/v1/worlds/{world}/edits",
                                  json={"edits": [{"op": "box", "min": [1, 1, 1], "max": [5, 5, 5], "colour": 3}]})
                    if r.status_code == 200:
                        written.append(r.json()["version"])
                    time.sleep(0.05)

        thread = threading.Thread(target=writer)
        thread.start()
        time.sleep(1.0)
        os.kill(victim["pid"], signal.SIGKILL)
        killed_at, before = time.monotonic(), len(written)
        while len(written) < before + 10 and time.monotonic() < killed_at + 120:
            time.sleep(0.1)
        assert len(written) >= before + 10, "the engine did not serve again"
        stop.set()
        thread.join(timeout=60)
        server.process.terminate()
        assert server.process.wait(timeout=60) == 0
    finally:
        stop.set()
        server.stop()
    log = server.log_path.read_text(errors="replace")
    assert "the Ray cluster has 0 GPUs: each engine asks for 0, so the engines run on CPU devices" in log
    assert "SIGTERM received" not in log, log[-3000:]
    assert "A worker died or was killed" not in log, log[-3000:]
    assert "not sent" not in log
    assert log.count(f"engine {victim['engine']} was restarted") == 1, log[-3000:]
    assert log.count("messages nobody waited for were dropped while it was away") <= 1, log[-3000:]
