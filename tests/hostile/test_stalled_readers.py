"""WebSocket peers that stop reading (``api/connections.py``, ``GuardedWebSocketProtocol``): a
client that subscribes and sends pings but never reads, with a small receive buffer, is aborted
once it has taken nothing for ``ws_send_timeout_s``, logged and counted, while others are
served; a client that reads slowly keeps its connection."""

from __future__ import annotations

import base64
import os
import re
import socket
import struct
import time

from websockets.sync.client import connect

from sdfserver import wire

SEND_TIMEOUT_S = 1.0
FLAGS = ["--ws-send-timeout-s", str(SEND_TIMEOUT_S), "--max-world-voxels", str(1 << 21),
         "--memory-budget-bytes", str(96 << 20)]
SIDE = 128  # a packed subscription to the whole world sends 4 MiB at once: more than socket buffers hold
SUBSCRIBE = {"type": "subscribe", "id": 0, "min": [0, 0, 0], "max": [SIDE] * 3, "format": "packed"}


def masked_frame(message: dict) -> bytes:
    """A binary frame as a client must send it (RFC 6455 §5.2: masked), of under 64 KiB."""
    payload, mask = wire.encode(message), os.urandom(4)
    n = len(payload)
    length = bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack("!H", n)
    return bytes([0x82]) + length + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


def raw_stream(server, world: str) -> socket.socket:
    """A WebSocket to ``world``'s stream with a small receive window; of what the server sends,
    only the handshake's answer is read."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connecting: the window offered
    sock.connect(("127.0.0.1", server.port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(f"GET /v1/worlds/{world}/stream HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                 f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
    answer = b""
    while not answer.endswith(b"\r\n\r\n"):
        answer += sock.recv(1)
    assert answer.startswith(b"HTTP/1.1 101"), answer
    sock.sendall(masked_frame(SUBSCRIBE))
    return sock


def send_timeouts(server) -> float:
    text = server.http.get("/metrics").text
    return float(re.search(r"^sdfserver_websocket_send_timeouts_total (\S+)$", text, re.M).group(1))


def change_every_chunk(server, world: str, colour: int) -> None:
    box = {"op": "box", "min": [0, 0, 0], "max": [SIDE, SIDE - colour % 8 - 1, SIDE], "colour": colour}
    assert server.http.post(f"/v1/worlds/{world}/edits", json={"edits": [box]}).status_code == 200


def test_a_client_that_sends_and_never_reads_is_closed_and_others_are_served(start_server):
    server = start_server(*FLAGS)
    world = server.new_world(size=[SIDE] * 3, chunk_size=16)
    sock = raw_stream(server, world)
    sock.setblocking(False)
    ping = masked_frame({"type": "ping", "id": 1})
    started, closed_after = time.monotonic(), None
    for colour in range(1, 4):
        change_every_chunk(server, world, colour)
    while time.monotonic() - started < 20 and closed_after is None:  # under the 20 s ping interval
        try:
            sock.send(ping)
        except BlockingIOError:  # the server no longer reads from it either
            pass
        except (ConnectionResetError, BrokenPipeError):
            closed_after = time.monotonic() - started
        time.sleep(0.005)
    sock.close()
    assert closed_after is not None, "a client that never reads was not closed in 20 s"
    assert closed_after < 10 * SEND_TIMEOUT_S, closed_after
    log = server.log_path.read_text(errors="replace")
    assert "closing the WebSocket of 127.0.0.1" in log
    assert "Traceback" not in log  # the aborted connection's frames end its session, no error unhandled
    assert send_timeouts(server) == 1
    with connect(f"{server.ws_url}/v1/worlds/{world}/stream") as ws:  # others are served
        ws.send(wire.encode({"type": "ping", "id": 7}))
        assert wire.decode(ws.recv(timeout=10)) == {"type": "pong", "id": 7}
    assert server.http.get("/livez").status_code == 200


def test_a_client_that_reads_slowly_keeps_its_connection(start_server):
    server = start_server(*FLAGS)
    world = server.new_world(size=[SIDE] * 3, chunk_size=16)
    sock = raw_stream(server, world)
    sock.settimeout(10)
    change_every_chunk(server, world, 1)
    received, until = 0, time.monotonic() + 5 * SEND_TIMEOUT_S
    while time.monotonic() < until:  # about 80 KiB/s: far less than the server has to send
        data = sock.recv(4096)
        assert data, "the server closed a client that reads"
        received += len(data)
        time.sleep(0.05)
    sock.close()
    assert received > 100_000
    assert send_timeouts(server) == 0
