"""clients/loadtest at a set rate is an open loop: against a stand-in server that stalls once for
200 ms, the latencies (from when each request was due) show the stall in their p99, while the
service times (from when each request left) see it in one or two requests only."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Iterator

import pytest
from clients_support import CLIENTS, ROOT, env_with_paths

sys.path.insert(0, str(CLIENTS))
from loadtest.schedule import ClosedLoop, OpenLoop, schedule_for  # noqa: E402

STALL_S = 0.2
STALL_AT_EDIT = 100  # at 200 edits/s, half a second into the run
WORLD = {"id": "standin00001", "size": [32, 32, 32], "chunk_size": 16, "max_distance": 16,
         "algorithm": "exact", "version": 0}


class StallingServer(ThreadingHTTPServer):
    """Answers what the load test sends (create a world, post edits, delete it) one request at a
    time, as one engine would, and holds every request for ``STALL_S`` once: at the
    ``STALL_AT_EDIT``-th edit."""

    daemon_threads = True

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.engine = threading.Lock()
        self.edits = 0

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server_address[1]}"


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"  # keep-alive: each game client holds one connection
    disable_nagle_algorithm = True  # headers and body leave as two writes

    def do_POST(self) -> None:
        self.rfile.read(int(self.headers.get("content-length", 0)))
        server: StallingServer = self.server  # type: ignore[assignment]
        if self.path == "/v1/worlds":
            return self._answer(201, WORLD)
        with server.engine:
            server.edits += 1
            if server.edits == STALL_AT_EDIT:
                time.sleep(STALL_S)
            version = server.edits
        self._answer(200, {"version": version})

    def do_DELETE(self) -> None:
        self.send_response(204)
        self.send_header("content-length", "0")
        self.end_headers()

    def _answer(self, status: int, body: dict) -> None:
        content = json.dumps(body).encode()
        self.send_response(status)
        self.send_header("content-type", "application/json")
        self.send_header("content-length", str(len(content)))
        self.end_headers()
        self.wfile.write(content)

    def log_message(self, format: str, *args) -> None:  # noqa: A002  (quiet: pytest shows failures)
        pass


@pytest.fixture
def stalling_server() -> Iterator[StallingServer]:
    server = StallingServer()
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def _loadtest(url: str, tmp_path, *args: str) -> tuple[str, dict]:
    out = tmp_path / "result.json"
    proc = subprocess.run(
        [sys.executable, str(CLIENTS / "loadtest"), "--url", url, "--read-every", "0", "--quiet",
         "--json", str(out), *args],
        cwd=ROOT, env=env_with_paths(), capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout, json.loads(out.read_text())


def test_a_stall_shows_in_the_latencies_at_a_set_rate(stalling_server, tmp_path):
    rate, duration_s = 200, 2.0
    stdout, result = _loadtest(stalling_server.url, tmp_path, "--clients", "2", "--rate", str(rate),
                               "--duration", str(duration_s))
    assert result["errors"]["count"] == 0 and stalling_server.edits >= STALL_AT_EDIT
    edits, schedule = result["edits"], result["schedule"]
    latency, service = edits["latency_ms"], edits["service_time_ms"]
    # Every request due during the stall waited for it: about 40 of 400, so the p99 is in the stall.
    assert latency["p99"] >= 0.75 * STALL_S * 1e3, (latency, service)
    assert latency["max"] >= 0.9 * STALL_S * 1e3
    # Timed from when they left, the requests held back by the stall look fast: only the one or two
    # in flight when it began waited for it.
    assert service["p99"] < 0.5 * STALL_S * 1e3 <= service["max"]
    assert all(latency[k] >= service[k] - 1e-6 for k in ("p50", "p95", "p99", "max", "min"))
    # The schedule did not slide: what was due during the stall still left, late, and was counted.
    assert edits["count"] >= 0.9 * rate * duration_s
    assert schedule["loop"] == "open" and schedule["latency_from"] == "due" and schedule["rate_per_s"] == rate
    assert schedule["sent"] == edits["count"]
    # Each client had about 19 slots come due while it waited out the stall.
    assert schedule["missed"] >= 0.25 * STALL_S * rate and schedule["late"] >= 0.25 * STALL_S * rate
    assert schedule["send_lag_ms"]["max"] >= 0.75 * STALL_S * 1e3
    # Every slot due before the end either left or is counted as never sent.
    assert abs(schedule["sent"] + schedule["unsent_at_end"] - rate * duration_s) <= 2
    assert f"open loop at {rate}/s" in stdout and "service time" in stdout
    assert f"{schedule['missed']} due while their client still waited" in stdout


def test_closed_loop_says_so_and_times_from_the_send(stalling_server, tmp_path):
    stdout, result = _loadtest(stalling_server.url, tmp_path, "--clients", "2", "--requests", "40")
    assert result["schedule"] == {"loop": "closed", "latency_from": "send"}
    assert result["edits"]["count"] == 40 and "service_time_ms" not in result["edits"]
    assert "closed loop (no --rate)" in stdout and "service time" not in stdout


def test_open_loop_slots_are_fixed_and_interleaved():
    start = 100.0
    first = [schedule_for(i, 4, 400.0, start) for i in range(4)]
    assert all(isinstance(s, OpenLoop) for s in first) and isinstance(schedule_for(0, 4, 0.0, start), ClosedLoop)
    assert [s.next_due() for s in first] == pytest.approx([100.0, 100.0025, 100.005, 100.0075])
    late = first[1]
    late.handed_out = 3  # three slots taken, however late they left: the fourth is still due on time
    assert late.next_due() == pytest.approx(100.0025 + 3 * 0.01)
    # The last slot handed out (100.0225) and those after it before the deadline never left.
    assert late.unsent_before(100.05) == 3 and late.unsent_before(100.02) == 0
    assert ClosedLoop().unsent_before(1e9) == 0
