"""What only the front processes (``--fronts N``) can get wrong: the connection hand-over to the
server process (bytes the front read vs bytes still in the socket, keep-alive across it,
pipelining), keys and the rate limit enforced once in the server process, fronts that die
or outlive their server, and the byte count they report to /metrics.

The generic API tests already run against ``--fronts 2`` (conftest's ``server``); these start
servers of their own, on raw sockets where the bytes on the wire matter.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import time
from pathlib import Path
from typing import Callable, TypeVar

import httpx
import numpy as np
import pytest

from sdfserver import wire

from server_process import ServerProcess

T = TypeVar("T")
FRONTS = 2
WORLD = {"size": [16, 16, 16], "chunk_size": 8, "max_distance": 6}
SPHERE = {"op": "sphere", "center": [8, 8, 8], "radius": 3.5, "colour": 7}
ALICE_TOKEN, BOB_TOKEN = "alice-token-0123456789", "bob-token-0123456789abc"
ALICE = {"authorization": f"Bearer {ALICE_TOKEN}"}
BOB = {"authorization": f"Bearer {BOB_TOKEN}"}
RATE_PER_S, BURST = 1, 3


# -- helpers -----------------------------------------------------------------------------------------


def wait_until(check: Callable[[], T], timeout_s: float, what: str, every_s: float = 0.05) -> T:
    """Poll ``check`` until it answers something true; fail naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"not within {timeout_s:g} s: {what} (last: {value!r})")
        time.sleep(every_s)


def front_pids(server_pid: int) -> set[int]:
    """The server process's children that are front processes."""
    try:
        children = Path(f"/proc/{server_pid}/task/{server_pid}/children").read_text().split()
    except OSError:
        return set()
    pids = set()
    for pid in map(int, children):
        try:
            if b"sdfserver.api.front" in Path(f"/proc/{pid}/cmdline").read_bytes():
                pids.add(pid)
        except OSError:
            pass
    return pids


def gone(pid: int) -> bool:
    """The process has exited: no /proc entry, or a zombie waiting for a parent to reap it."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat.rpartition(")")[2].split()[0] in ("Z", "X")


def tcp_rows() -> list[tuple[int, int, str, int]]:
    """(local port, remote port, state, inode) of every IPv4 TCP socket."""
    rows = []
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        f = line.split()
        rows.append((int(f[1].split(":")[1], 16), int(f[2].split(":")[1], 16), f[3], int(f[9])))
    return rows


def listeners(port: int) -> int:
    """Listening sockets on ``port``: one per front that is up (the server process's own is bound only)."""
    return sum(1 for local, _, state, _ in tcp_rows() if local == port and state == "0A")


def holders(server: ServerProcess, client: socket.socket) -> set[int]:
    """The pids (server process or a front) that hold the server's end of ``client``'s connection."""
    client_port = client.getsockname()[1]
    inodes = {inode for local, remote, _, inode in tcp_rows() if local == server.port and remote == client_port}
    found = set()
    for pid in {server.process.pid} | front_pids(server.process.pid):
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if target.startswith("socket:[") and int(target[8:-1]) in inodes:
                found.add(pid)
    return found


def http_request(method: str, path: str, body: bytes = b"", headers: dict | None = None) -> bytes:
    head = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1"]
    headers = dict(headers or {})
    if body or method in ("POST", "PUT", "PATCH"):
        headers.setdefault("Content-Length", str(len(body)))
    head += [f"{name}: {value}" for name, value in headers.items()]
    return ("\r\n".join(head) + "\r\n\r\n").encode() + body


def json_request(method: str, path: str, content: object, headers: dict | None = None) -> bytes:
    return http_request(method, path, json.dumps(content).encode(),
                        {"Content-Type": "application/json", **(headers or {})})


class Raw:
    """One TCP connection, requests written byte for byte and answers parsed here (keep-alive
    and pipelining exactly as sent, which httpx does not promise)."""

    def __init__(self, port: int, timeout_s: float = 10.0):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout_s)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # each send its own segment
        self.buffer = b""

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def _fill(self) -> None:
        chunk = self.sock.recv(1 << 16)
        if not chunk:
            raise EOFError(f"the server closed the connection; unparsed: {self.buffer[:200]!r}")
        self.buffer += chunk

    def answer(self) -> tuple[int, dict[str, str], bytes]:
        """(status, lower-cased headers, body) of the next answer."""
        while b"\r\n\r\n" not in self.buffer:
            self._fill()
        head, self.buffer = self.buffer.split(b"\r\n\r\n", 1)
        status_line, *lines = head.decode("latin-1").split("\r\n")
        headers = {}
        for line in lines:
            name, _, value = line.partition(":")
            headers[name.strip().lower()] = value.strip()
        size = int(headers.get("content-length", 0))
        while len(self.buffer) < size:
            self._fill()
        body, self.buffer = self.buffer[:size], self.buffer[size:]
        return int(status_line.split()[1]), headers, body

    def answers_until_closed(self) -> list[tuple[int, dict[str, str], bytes]]:
        out = []
        while True:
            try:
                out.append(self.answer())
            except EOFError:
                return out

    def close(self) -> None:
        self.sock.close()


def start(tmp_path_factory, name: str, *flags: str) -> ServerProcess:
    """A server with ``FRONTS`` fronts, returned once every front listens (readiness needs only one)."""
    server = ServerProcess(tmp_path_factory.mktemp(name) / "data", "--fronts", str(FRONTS),
                           "--max-wait-ms", "1500", *flags).wait_ready()
    try:
        wait_until(lambda: listeners(server.port) == FRONTS, 15, f"{FRONTS} fronts listening")
    except AssertionError:
        server.stop()
        raise
    return server


def create_world(server: ServerProcess, headers: dict | None = None, **overrides) -> str:
    r = httpx.post(server.url + "/v1/worlds", json={**WORLD, **overrides}, headers=headers)
    assert r.status_code == 201, r.text
    return r.json()["id"]


def describe(server: ServerProcess, world_id: str, headers: dict | None = None) -> dict:
    r = httpx.get(f"{server.url}/v1/worlds/{world_id}", headers=headers)
    assert r.status_code == 200, r.text
    return r.json()


def metric(server: ServerProcess, name: str) -> float:
    for line in httpx.get(server.url + "/metrics").text.splitlines():
        if line.startswith(name + " "):
            return float(line.split()[1])
    raise KeyError(name)


def assert_no_tracebacks(server: ServerProcess) -> None:
    """The server's and its fronts' log (they share it) holds no traceback."""
    text = server.log_path.read_text(errors="replace")
    found = text.split("Traceback (most recent call last)")[1:]
    assert not found, f"{len(found)} tracebacks in {server.log_path}; the first:\n{found[0][:2000]}"


@pytest.fixture(scope="module")
def fronted(tmp_path_factory):
    """One open server with two fronts, shared by the tests that leave it as they found it."""
    server = start(tmp_path_factory, "fronted")
    yield server
    server.stop()
    assert_no_tracebacks(server)


# -- the hand-over -----------------------------------------------------------------------------------


def _split_cases() -> dict[str, tuple[bytes, list[int]]]:
    small = json_request("POST", "/v1/worlds", WORLD)
    head_end = small.index(b"\r\n\r\n") + 4
    # Whitespace is valid JSON: a body far above a hand-over part (60 KiB) and the front's first read
    body = json.dumps(WORLD).encode() + b" " * 300_000
    large = http_request("POST", "/v1/worlds", body, {"Content-Type": "application/json"})
    return {
        "headers-then-body": (small, [head_end]),
        "inside-request-line": (small, [7]),
        "inside-headers": (small, [head_end - 20]),
        "inside-body": (small, [head_end + 5]),
        "in-three-pieces": (small, [30, head_end + 2]),
        "large-body-one-send": (large, []),
    }


SPLITS = _split_cases()


@pytest.mark.parametrize("case", list(SPLITS))
def test_handed_over_request_split_across_segments(fronted, case):
    """A request the server process answers, arriving in pieces 50 ms apart: the front hands
    the connection over with the bytes it has read, and the server process must read the
    rest from the socket. Any lost or repeated byte breaks the JSON or the framing."""
    request, cuts = SPLITS[case]
    conn = Raw(fronted.port)
    try:
        pieces = [request[a:b] for a, b in zip([0, *cuts], [*cuts, len(request)])]
        for i, piece in enumerate(pieces):
            if i:
                time.sleep(0.05)  # its own segment, read by whoever holds the socket by then
            conn.send(piece)
        status, headers, body = conn.answer()
    finally:
        conn.close()
    assert status == 201, body
    world = json.loads(body)
    assert world["size"] == WORLD["size"] and world["version"] == 0
    assert headers["location"] == f"/v1/worlds/{world['id']}"
    assert describe(fronted, world["id"])["id"] == world["id"]


def test_handed_over_request_with_expect_100_continue(fronted):
    """``Expect: 100-continue`` on a request that is handed over: the 100 comes (once) from the
    server process, which then reads the body the client sends only after it."""
    body = json.dumps(WORLD).encode()
    conn = Raw(fronted.port)
    try:
        conn.send(http_request("POST", "/v1/worlds", headers={
            "Content-Type": "application/json", "Content-Length": str(len(body)), "Expect": "100-continue"}))
        status, _, _ = conn.answer()
        assert status == 100
        conn.send(body)
        status, _, answer = conn.answer()
        assert status == 201, answer
        assert json.loads(answer)["size"] == WORLD["size"]
        assert conn.buffer == b""  # nothing more (a second 100, say)
    finally:
        conn.close()


def test_keep_alive_connection_moves_once_and_stays_correct(fronted, ref):
    """One keep-alive connection: an edit (a front answers), a describe (the connection moves to
    the server process), then a field read and another edit, now answered by the server
    process's own lane. Each answer is right, and the socket is where it should be."""
    world_id = create_world(fronted)
    conn = Raw(fronted.port)
    try:
        conn.send(json_request("POST", f"/v1/worlds/{world_id}/edits", {"edits": [SPHERE]}))
        status, headers, body = conn.answer()
        assert status == 200, body
        version = json.loads(body)["version"]
        assert version == 1
        server_pid = fronted.process.pid
        served_by = holders(fronted, conn.sock)
        assert len(served_by) == 1 and served_by <= front_pids(server_pid), served_by

        conn.send(http_request("GET", f"/v1/worlds/{world_id}"))
        status, headers, body = conn.answer()
        assert status == 200, body
        assert json.loads(body)["version"] == version
        assert headers.get("connection") != "close"
        wait_until(lambda: holders(fronted, conn.sock) == {server_pid}, 5, "the connection held by the server only")

        conn.send(http_request("GET", f"/v1/worlds/{world_id}/field?min_version={version}",
                               headers={"Accept": wire.CONTENT_TYPE}))
        status, headers, body = conn.answer()
        assert status == 200, body
        msg = wire.decode(body)
        field = np.frombuffer(msg["data"], dtype=msg["dtype"]).reshape(msg["shape"])
        voxels = np.zeros(WORLD["size"][::-1], dtype=np.uint8)
        ref.apply(voxels, [SPHERE])
        np.testing.assert_array_equal(field, ref.distance(voxels, WORLD["max_distance"]))
        assert msg["version"] >= version

        conn.send(json_request("POST", f"/v1/worlds/{world_id}/edits",
                               {"edits": [{**SPHERE, "center": [2, 2, 2]}]}))
        status, headers, body = conn.answer()
        assert status == 200, body
        assert json.loads(body)["version"] == version + 1
        assert holders(fronted, conn.sock) == {server_pid}
    finally:
        conn.close()


def test_request_pipelined_behind_a_lane_request(fronted):
    """An edit and a describe in one send: the front serves the edit, but cannot hand over a
    request whose bytes it already fed its parser. The edit must still get its own 200 (it
    is applied), then the describe a 400 saying why, then the connection closes. HTTP/1.1
    answers in order: a 400 in the edit's place would tell the client its applied edit failed
    (which the first version of ``FrontProtocol._hand_over`` did).
    """
    world_id = create_world(fronted)
    before = describe(fronted, world_id)["version"]
    conn = Raw(fronted.port)
    try:
        conn.send(json_request("POST", f"/v1/worlds/{world_id}/edits", {"edits": [SPHERE]})
                  + http_request("GET", f"/v1/worlds/{world_id}"))
        answers = conn.answers_until_closed()
    finally:
        conn.close()
    after = describe(fronted, world_id)["version"]
    statuses = [status for status, _, _ in answers]
    assert after == before + 1, f"the edit was applied {after - before} times"
    assert statuses == [200, 400], (f"answers {[(s, b[:120]) for s, _, b in answers]}; the edit was applied "
                                    f"(version {before} -> {after})")
    assert json.loads(answers[0][2]) == {"version": before + 1}
    assert b"pipelined" in answers[1][2]
    assert answers[1][1].get("connection") == "close"


# -- what the fronts report ------------------------------------------------------------------------


def test_bytes_out_of_front_reads_reach_metrics(fronted):
    """A front counts the bytes of the bodies it sends and reports them every second: the
    server's /metrics must grow by at least the bodies of field reads the fronts answered."""
    world_id = create_world(fronted, size=[32, 32, 32])  # 64 KiB packed reads: well above other traffic
    before = metric(fronted, "sdfserver_bytes_out_total")
    sent = 0
    for _ in range(6):  # fresh connections: each one a front's
        r = httpx.get(f"{fronted.url}/v1/worlds/{world_id}/field", params={"format": "packed"},
                      headers={"accept": wire.CONTENT_TYPE})
        assert r.status_code == 200, r.text
        assert "content-encoding" not in r.headers
        sent += len(r.content)
    wait_until(lambda: metric(fronted, "sdfserver_bytes_out_total") - before >= sent, 3.5,
               f"sdfserver_bytes_out_total grown by {sent}", every_s=0.1)


# -- a front that dies -------------------------------------------------------------------------------


def test_a_killed_front_is_started_again(fronted):
    """SIGKILL one front: the server process starts another in its place (same count, a new pid,
    listening), and edits over fresh connections keep succeeding, in order."""
    server_pid = fronted.process.pid
    old = front_pids(server_pid)
    assert len(old) == FRONTS, old
    victim = min(old)
    os.kill(victim, signal.SIGKILL)
    new = wait_until(lambda: (lambda now: now if len(now) == FRONTS and victim not in now else None)(
        front_pids(server_pid)), 15, "a front started in place of the killed one")
    assert old - {victim} <= new
    wait_until(lambda: listeners(fronted.port) == FRONTS, 15, f"{FRONTS} fronts listening again")
    assert "starting it again" in fronted.output()

    world_id = create_world(fronted)
    versions = []
    for _ in range(20):
        r = httpx.post(f"{fronted.url}/v1/worlds/{world_id}/edits", json={"edits": [SPHERE]})
        assert r.status_code == 200, r.text
        versions.append(r.json()["version"])
    assert versions == list(range(1, 21))


def test_fronts_exit_with_their_server(tmp_path_factory):
    """SIGKILL the server process: each front loses its link and must exit (not keep the port
    and answer 503s forever), even with a client's keep-alive connection open on it."""
    server = start(tmp_path_factory, "doomed")
    pids = front_pids(server.process.pid)
    try:
        assert len(pids) == FRONTS, pids
        world_id = create_world(server)
        with httpx.Client(base_url=server.url) as idle:  # a connection left open on a front
            assert idle.get(f"/v1/worlds/{world_id}/field").status_code == 200
            server.kill()
            wait_until(lambda: all(gone(pid) for pid in pids), 10, f"fronts {sorted(pids)} exited")
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(("127.0.0.1", server.port), timeout=2).close()
        assert_no_tracebacks(server)
    finally:  # a front that failed to exit is an orphan nobody else stops
        server.kill()
        for pid in pids:
            if not gone(pid):
                os.kill(pid, signal.SIGKILL)


# -- keys and the rate limit, checked once in the server process ----------------------------------------


@pytest.fixture(scope="module")
def keyed(tmp_path_factory):
    server = start(tmp_path_factory, "keyed", "--api-keys", f"alice:{ALICE_TOKEN},bob:{BOB_TOKEN}")
    yield server
    server.stop()
    assert_no_tracebacks(server)


def test_api_keys_through_fronts(keyed):
    """A front authenticates; the server process checks the owner. No key: 401 from the front,
    with WWW-Authenticate. Bob on Alice's world through the lane: 404, word for word as a
    world that does not exist, and nothing applied. Alice: 200."""
    alice_world = create_world(keyed, ALICE)
    bob_world = create_world(keyed, BOB)
    lane = [("POST", "edits", {"json": {"edits": [SPHERE]}}),
            ("GET", "field", {}),
            ("POST", "query", {"json": {"points": [[1, 2, 3]]}})]

    for method, what, kwargs in lane:
        for headers in ({}, {"authorization": "Bearer not-a-key-0123456789"}):
            r = httpx.request(method, f"{keyed.url}/v1/worlds/{alice_world}/{what}", headers=headers, **kwargs)
            assert r.status_code == 401, (what, r.text)
            assert r.headers["www-authenticate"].startswith("Bearer")
            assert r.json()["error"]["code"] == "unauthorized"

        theirs = httpx.request(method, f"{keyed.url}/v1/worlds/{alice_world}/{what}", headers=BOB, **kwargs)
        missing = httpx.request(method, f"{keyed.url}/v1/worlds/nosuchworld/{what}", headers=BOB, **kwargs)
        assert theirs.status_code == missing.status_code == 404, (what, theirs.text, missing.text)
        assert theirs.json() == json.loads(missing.text.replace("nosuchworld", alice_world))

    assert describe(keyed, alice_world, ALICE)["version"] == 0  # Bob's edit went nowhere
    for world_id, key in ((alice_world, ALICE), (bob_world, BOB)):
        r = httpx.post(f"{keyed.url}/v1/worlds/{world_id}/edits", json={"edits": [SPHERE]}, headers=key)
        assert r.status_code == 200, r.text
        assert r.json() == {"version": 1}


@pytest.fixture(scope="module")
def limited(tmp_path_factory):
    server = start(tmp_path_factory, "limited", "--rate-limit-per-s", str(RATE_PER_S),
                   "--rate-limit-burst", str(BURST))
    yield server
    server.stop()
    assert_no_tracebacks(server)


def test_rate_limit_is_one_bucket_across_fronts(limited):
    """Quick lane requests over separate connections (so both fronts serve some): one bucket in
    the server process lets through at most the burst plus what refills meanwhile, and the rest
    get 429 with Retry-After. A bucket per front would let about twice the burst through."""
    began = time.monotonic()
    world_id = create_world(limited)  # the bucket's first token
    answers = [httpx.get(f"{limited.url}/v1/worlds/{world_id}/field") for _ in range(12)]
    elapsed = time.monotonic() - began
    ok = [r for r in answers if r.status_code == 200]
    limited_answers = [r for r in answers if r.status_code == 429]
    assert len(ok) + len(limited_answers) == len(answers), [r.status_code for r in answers]
    assert limited_answers, "no request was rate-limited"
    for r in limited_answers:
        assert int(r.headers["retry-after"]) >= 1
        assert r.json()["error"]["code"] == "rate_limited"
    # the bucket holds BURST, refills RATE_PER_S, and the creation took one; +1 for rounding
    allowed = BURST - 1 + int(elapsed * RATE_PER_S) + 1
    assert 1 <= len(ok) <= allowed, f"{len(ok)} of {len(answers)} passed in {elapsed:.2f} s; at most {allowed}"
