"""A response leaves in one write (``connections.CoalescedWrites``): uvicorn writes its head and
body separately, and each write on a TCP socket may wake the client once more."""

from __future__ import annotations

import asyncio
import socket

from sdfserver.api.connections import COALESCED_COPY_BYTES, CoalescedWrites


def test_each_answer_arrives_in_one_piece(server):
    host, port = server.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=10) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for _ in range(40):
            sock.sendall(b"GET /livez HTTP/1.1\r\nHost: t\r\n\r\n")
            piece = sock.recv(1 << 16)  # the first piece the kernel has for us
            head, _, body = piece.partition(b"\r\n\r\n")
            length = next(int(line.split(b":")[1]) for line in head.lower().split(b"\r\n")
                          if line.startswith(b"content-length:"))
            assert head.startswith(b"HTTP/1.1 200") and length > 0 and len(body) == length, piece


class Recorder:
    def __init__(self):
        self.calls: list[tuple[str, object]] = []
        self.closing = False

    def write(self, data):
        self.calls.append(("write", bytes(data)))

    def writelines(self, pieces):
        self.calls.append(("writelines", [bytes(p) for p in pieces]))

    def close(self):
        self.calls.append(("close", None))
        self.closing = True

    def abort(self):
        self.calls.append(("abort", None))

    def is_closing(self):
        return self.closing

    def get_write_buffer_size(self):
        return 0

    def get_extra_info(self, name, default=None):
        return ("extra", name)


def test_a_write_waits_for_the_next_or_for_the_turn_to_end():
    async def run() -> list:
        recorder = Recorder()
        writes = CoalescedWrites(recorder, asyncio.get_running_loop())
        writes.write(bytearray(b"head "))
        assert recorder.calls == [] and writes.get_write_buffer_size() == 5
        writes.write(b"body")  # the pair leaves at once, in one write
        assert recorder.calls == [("write", b"head body")]
        large = b"x" * (COALESCED_COPY_BYTES + 1)
        writes.write(b"head ")
        writes.write(large)  # not copied to join it
        assert recorder.calls[-1] == ("writelines", [b"head ", large])
        writes.write(b"alone")
        await asyncio.sleep(0)  # the turn ends
        assert recorder.calls[-1] == ("write", b"alone")
        writes.write(b"last")
        writes.close()  # sent before the transport closes
        writes.write(b"late")
        await asyncio.sleep(0)  # the transport is closing: nothing more is written
        writes.write(b"dropped")
        writes.abort()
        assert writes.get_extra_info("peername") == ("extra", "peername")
        return recorder.calls[-3:]

    assert asyncio.run(run()) == [("write", b"last"), ("close", None), ("abort", None)]
