"""HTTP/1.1 pipelining on every route: requests sent back to back in one packet are all answered,
in order, whichever API process holds the connection."""

from __future__ import annotations

import json
import socket


def exchange(url: str, data: bytes, answers: int, timeout_s: float = 30.0) -> list[tuple[int, bytes]]:
    """Send ``data`` in one write; read ``answers`` responses (status, body)."""
    host, port = url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=timeout_s) as sock:
        sock.sendall(data)
        buffer, out = b"", []
        while len(out) < answers:
            while b"\r\n\r\n" not in buffer:
                chunk = sock.recv(1 << 16)
                assert chunk, f"the connection closed after {len(out)} answers"
                buffer += chunk
            head, _, buffer = buffer.partition(b"\r\n\r\n")
            lines = head.split(b"\r\n")
            headers = dict(line.lower().split(b": ", 1) for line in lines[1:])
            length = int(headers.get(b"content-length", b"0"))
            while len(buffer) < length:
                chunk = sock.recv(1 << 16)
                assert chunk, "the connection closed inside a body"
                buffer += chunk
            out.append((int(lines[0].split()[1]), buffer[:length]))
            buffer = buffer[length:]
        return out


def test_twenty_pipelined_gets_are_all_answered(server):
    answers = exchange(server.url, b"GET /livez HTTP/1.1\r\nHost: t\r\n\r\n" * 20, 20)
    assert [status for status, _ in answers] == [200] * 20


def test_a_read_and_an_edit_in_one_packet_are_both_answered(server):
    world = server.create_world(size=[16, 16, 16], chunk_size=8, max_distance=8)["id"]
    edit = json.dumps({"edits": [{"op": "box", "min": [1, 1, 1], "max": [3, 3, 3], "colour": 4}]}).encode()
    data = (f"GET /v1/worlds/{world}/field HTTP/1.1\r\nHost: t\r\naccept: application/json\r\n\r\n"
            f"POST /v1/worlds/{world}/edits HTTP/1.1\r\nHost: t\r\ncontent-type: application/json\r\n"
            f"content-length: {len(edit)}\r\n\r\n").encode() + edit
    data += f"GET /v1/worlds/{world}/field?min_version=1 HTTP/1.1\r\nHost: t\r\naccept: application/json\r\n\r\n".encode()
    (read_status, read), (edit_status, edited), (after_status, after) = exchange(server.url, data, 3)
    assert (read_status, edit_status, after_status) == (200, 200, 200)
    assert json.loads(read)["version"] == 0 and json.loads(edited) == {"version": 1}
    assert json.loads(after)["version"] == 1
    server.http.delete(f"/v1/worlds/{world}")
