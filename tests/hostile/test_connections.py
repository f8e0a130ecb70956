"""Connection-level limits, enforced before a key is checked or a body read
(``sdfserver/api/connections.py``, uvicorn's options in ``api/worker.py``, the subscription
limits in ``engine/service.py``): raw sockets against a real server on loopback."""

from __future__ import annotations

import asyncio
import socket
import time

import httpx
import msgpack
import pytest
import websockets

from sdfserver import wire
from server_process import tree_rss_bytes

LIMITS = ["--workers", "1", "--max-header-bytes", "4096", "--max-header-count", "20",
          "--header-timeout-s", "1.5", "--idle-timeout-s", "1.5", "--max-connections", "40",
          "--max-subscriptions", "3", "--max-subscriptions-per-key", "2", "--ws-ping-interval-s", "0"]


OPENED: list[socket.socket] = []


@pytest.fixture(autouse=True)
def close_sockets():
    yield
    while OPENED:
        OPENED.pop().close()


def connect(server) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    OPENED.append(sock)
    return sock


def answer(sock: socket.socket, timeout_s: float = 10) -> bytes:
    """Everything the server sends until it closes the connection (or the timeout)."""
    sock.settimeout(timeout_s)
    data = b""
    try:
        while chunk := sock.recv(65536):
            data += chunk
    except (TimeoutError, ConnectionResetError):
        pass
    return data


def status_of(data: bytes) -> int | None:
    return int(data.split(b" ", 2)[1]) if data.startswith(b"HTTP/1.1 ") else None


def served(server) -> bool:
    return httpx.get(server.url + "/livez", timeout=5).status_code == 200


@pytest.fixture
def server(start_server):
    return start_server(*LIMITS)


def test_a_header_past_the_byte_limit_is_431_without_reading_it_all(server):
    before = tree_rss_bytes(server.process.pid)
    sock = connect(server)
    sock.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\nx-long: ")
    sent = 0
    try:
        for _ in range(4096):  # up to 64 MiB of one header that never ends
            sock.sendall(b"a" * 16384)
            sent += 16384
    except (BrokenPipeError, ConnectionResetError):
        pass
    # what the sockets' buffers took on loopback, not what the server read
    assert sent < 16 << 20, f"the server took {sent} bytes of one header"
    assert tree_rss_bytes(server.process.pid) - before < 32 << 20
    assert status_of(answer(sock)) in (431, None)  # a reset may race the 431 away; the read stopped
    assert served(server)


def test_a_complete_header_past_the_byte_limit_is_431(server):
    sock = connect(server)
    sock.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\nx-long: " + b"a" * 5000 + b"\r\n\r\n")
    data = answer(sock)
    assert status_of(data) == 431 and b"4096 bytes" in data
    ok = connect(server)
    ok.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\nx-short: " + b"a" * 1000 + b"\r\nconnection: close\r\n\r\n")
    assert status_of(answer(ok)) == 200


def test_too_many_header_lines_is_431(server):
    sock = connect(server)
    lines = b"".join(b"x-%d: 1\r\n" % i for i in range(30))
    sock.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\n" + lines + b"\r\n")
    data = answer(sock)
    assert status_of(data) == 431 and b"header lines" in data


def test_slow_headers_and_idle_connections_are_closed_while_others_are_served(server):
    slow, idle, kept = connect(server), connect(server), connect(server)
    slow.sendall(b"GET /livez HTTP/1.1\r\n")
    kept.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\n\r\n")
    started = time.monotonic()
    for _ in range(4):  # a header line every 0.5 s: slower than the header timeout allows in all
        time.sleep(0.5)
        assert served(server)
        try:
            slow.sendall(b"x-slow: 1\r\n")
        except (BrokenPipeError, ConnectionResetError):
            break
    assert status_of(answer(slow)) == 408
    assert status_of(answer(idle)) == 408 and time.monotonic() - started < 6  # never sent a byte: closed too
    first = answer(kept)  # answered, then closed after the idle time between requests
    assert status_of(first) == 200 and time.monotonic() - started < 6


def test_a_kept_alive_connections_next_request_with_slow_headers_is_408(server):
    sock = connect(server)
    sock.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\n\r\n")
    sock.settimeout(5)
    first = b""
    while not first.endswith(b"}"):  # the head and the body may come in two pieces
        piece = sock.recv(65536)
        assert piece, f"the connection closed after {first!r}"
        first += piece
    assert status_of(first) == 200
    started = time.monotonic()
    sock.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\n")  # and the rest never comes
    second = answer(sock, 6)
    assert status_of(second) == 408 and b"did not arrive within" in second
    assert time.monotonic() - started < 4


def test_connections_past_the_limit_are_refused_503_and_others_served_after(server):
    held = []
    for _ in range(45):
        sock = connect(server)
        sock.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\n")  # headers never finished: held
        held.append(sock)
    time.sleep(0.3)
    refused = 0
    for sock in held[-10:]:
        sock.settimeout(0.5)
        try:
            data = sock.recv(4096)
        except TimeoutError:
            continue
        refused += status_of(data) == 503
    assert refused >= 5, refused  # 40 held, the rest answered 503 at once
    for sock in held:
        sock.close()
    time.sleep(0.3)
    assert served(server)


def test_a_post_asking_for_a_websocket_upgrade_is_400(server):
    sock = connect(server)
    sock.sendall(b"POST /v1/worlds HTTP/1.1\r\nhost: x\r\nconnection: Upgrade\r\nupgrade: websocket\r\n"
                 b"sec-websocket-version: 13\r\nsec-websocket-key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                 b"content-length: 2\r\n\r\n{}")
    data = answer(sock)
    assert status_of(data) == 400 and b"GET" in data


def test_a_streamed_body_past_the_limit_is_refused_before_it_is_all_sent(start_server):
    server = start_server(*LIMITS)  # max_request_bytes is 1 MiB (hostile_server.FLAGS)
    world = server.new_world()
    sock = connect(server)
    sock.sendall(f"POST /v1/worlds/{world}/edits HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n"
                 "transfer-encoding: chunked\r\n\r\n".encode())
    sent = 0
    try:
        for _ in range(256):  # 16 MiB offered in 64 KiB chunks
            sock.sendall(b"10000\r\n" + b" " * 65536 + b"\r\n")
            sent += 65536
    except (BrokenPipeError, ConnectionResetError):
        pass
    data = answer(sock, 5)
    assert status_of(data) in (413, None) and sent < 8 << 20, (data[:200], sent)
    assert server.http.get(f"/v1/worlds/{world}").json()["version"] == 0


KEYS = {"alice": "alice-token-0123456789", "bob": "bob-token-0123456789ab"}


def test_subscriptions_past_the_engine_and_key_limits_are_refused(start_server):
    server = start_server(*LIMITS, "--api-keys", ",".join(f"{k}:{t}:admin" for k, t in KEYS.items()))
    r = server.http.post("/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8},
                         headers={"authorization": f"Bearer {KEYS['alice']}"})
    world = r.json()["id"]
    region = {"min": [0, 0, 0], "max": [8, 8, 8]}

    async def outcome(ws, frame_id: int) -> str:
        """"subscribed" goes out at once; then the first chunks, or the engine's refusal."""
        await ws.send(wire.encode({"type": "subscribe", "id": frame_id, **region}))
        assert wire.decode(await asyncio.wait_for(ws.recv(), 10))["type"] == "subscribed"
        then = wire.decode(await asyncio.wait_for(ws.recv(), 10))
        return then["type"] if then["type"] == "chunks" else then["error"]["code"]

    async def scenario():
        url = f"{server.ws_url}/v1/worlds/{world}/stream?access_token="
        alice = [await websockets.connect(url + KEYS["alice"], max_size=None) for _ in range(3)]
        bob = [await websockets.connect(url + KEYS["bob"], max_size=None) for _ in range(2)]
        # alice: 2 a key; bob: 1 more makes the engine's 3, then none
        assert [await outcome(ws, 1) for ws in alice] == ["chunks", "chunks", "too_many_subscriptions"]
        assert [await outcome(ws, 1) for ws in bob] == ["chunks", "too_many_subscriptions"]
        await alice[0].close()  # its subscription leaves: room for one more
        await asyncio.sleep(0.5)
        assert await outcome(bob[1], 2) == "chunks"  # bob's second of 2, the engine's third
        assert await outcome(alice[2], 2) == "too_many_subscriptions"  # alice has room, the engine none
        for ws in alice[1:] + bob:
            await ws.close()

    asyncio.run(scenario())


def test_a_websocket_message_past_the_size_limit_closes_1009_and_deflate_is_not_offered(server):
    world = server.new_world()

    async def scenario():
        url = f"{server.ws_url}/v1/worlds/{world}/stream"
        ws = await websockets.connect(url, max_size=None, compression="deflate")
        assert "permessage-deflate" not in (ws.response.headers.get("sec-websocket-extensions") or "")
        with pytest.raises(websockets.ConnectionClosed) as closed:
            await ws.send(b"\x00" * ((1 << 20) + 1))  # the server may close before it is all written
            await asyncio.wait_for(ws.recv(), 10)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009

    asyncio.run(scenario())


def test_a_thousand_slow_clients_cost_little_memory(start_server):
    server = start_server(*LIMITS[:-8], "--max-connections", "2000", "--header-timeout-s", "3")
    before = tree_rss_bytes(server.process.pid)
    held = []
    for i in range(600):
        try:
            sock = connect(server)
            sock.sendall(b"GET /livez HTTP/1.1\r\nhost: x\r\nx-slow: " + b"a" * 3000)
            held.append(sock)
        except OSError:
            break
    assert served(server)
    grown = tree_rss_bytes(server.process.pid) - before
    assert grown < 200 << 20, grown
    time.sleep(4)
    closed = sum(1 for sock in held if status_of(answer(sock, 0.05)) == 408)
    assert closed >= len(held) * 0.9, (closed, len(held))


def test_a_small_body_of_many_empty_containers_is_refused_before_it_grows(start_server):
    # at most 1,000 voxel rows and query points: about 70,000 arrays and maps a message
    server = start_server(*LIMITS, "--max-voxels-per-batch", "1000", "--max-query-points", "1000")
    world = server.new_world()
    before = tree_rss_bytes(server.process.pid)
    # 400 arrays of 2,000 empty maps (each array within max_array_len): 800 KB on the wire, 800,000
    # dicts (about 50 MB) once decoded
    body = msgpack.packb({"edits": [[{}] * 2000] * 400})
    r = server.http.post(f"/v1/worlds/{world}/edits", content=body,
                         headers={"content-type": "application/msgpack"})
    assert r.status_code == 422 and "arrays and maps" in r.text, r.text
    assert tree_rss_bytes(server.process.pid) - before < 64 << 20
    assert server.http.get(f"/v1/worlds/{world}").json()["version"] == 0
    json_body = b'{"edits": [' + b",".join([b"[" + b",".join([b"{}"] * 2000) + b"]"] * 100) + b"]}"
    r = server.http.post(f"/v1/worlds/{world}/edits", content=json_body, headers={"content-type": "application/json"})
    assert r.status_code == 422 and "arrays and maps" in r.text, r.text
