"""The engine's stream sockets: addresses, length-prefixed frames, and a reader that cuts a byte
stream back into frames.

An engine listens at two addresses (``ipc:///path``: a Unix socket on this machine;
``tcp://host:port``: TCP, for engines on other machines). Every message is one frame: a 4-byte
little-endian length, then that many bytes (a msgspec-encoded message). The first frame on a
connection is the connecting API process's identity. A plain stream socket is one thread wake
per hop where a ZeroMQ socket is three (its I/O thread on each side, then the reader), and that
hop sits twice in every request.
"""

from __future__ import annotations

import os
import socket
from typing import Any, Callable
from urllib.parse import urlsplit

HEADER = 4
MAX_FRAME = 2**32 - 1
# A Unix socket's sender may have this much in flight (the system caps it at twice
# net.core.wmem_max): a megabyte query or answer is written in one call and read in a few,
# where the default (about 200 KiB) makes writer and reader take turns, a thread wake each.
UNIX_SEND_BUFFER = 4 << 20


def frame(payload: bytes) -> bytes:
    if len(payload) > MAX_FRAME:
        raise OverflowError(f"a message of {len(payload)} bytes passes the {MAX_FRAME}-byte frame limit")
    return len(payload).to_bytes(HEADER, "little") + payload


def encode_frame(encode_into: Callable[[Any, bytearray, int], None], message: Any) -> bytearray:
    """``message`` encoded straight after its frame's header (``encode_into``: a msgspec
    encoder's): a megabyte message is copied once, not again to put the header before it."""
    data = bytearray(HEADER)
    encode_into(message, data, HEADER)
    size = len(data) - HEADER
    if size > MAX_FRAME:
        raise OverflowError(f"a message of {size} bytes passes the {MAX_FRAME}-byte frame limit")
    data[:HEADER] = size.to_bytes(HEADER, "little")
    return data


def family_and_target(address: str) -> tuple[int, str | tuple[str, int]]:
    url = urlsplit(address)
    if url.scheme == "ipc":
        return socket.AF_UNIX, url.path
    if url.scheme == "tcp" and url.hostname and url.port:
        return socket.AF_INET, (url.hostname, url.port)
    raise ValueError(f"an engine address is ipc:///path or tcp://host:port, got {address!r}")


def listen(address: str) -> socket.socket:
    family, target = family_and_target(address)
    sock = socket.socket(family, socket.SOCK_STREAM)
    if family == socket.AF_UNIX:
        try:
            os.unlink(target)  # a socket file left by an engine that was killed
        except FileNotFoundError:
            pass
    else:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(target)
    sock.listen(128)
    return sock


def prepare(sock: socket.socket) -> None:
    """Small messages leave at once (no Nagle delay on TCP); large ones go in one write on a
    Unix socket (TCP sizes its buffers itself)."""
    if sock.family in (socket.AF_INET, socket.AF_INET6):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    elif sock.family == socket.AF_UNIX:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, UNIX_SEND_BUFFER)


class FrameReader:
    """Bytes in, whole frames out, in order; a large frame is gathered in one buffer of its
    size rather than by growing and cutting one. While one is, ``space()`` is the rest of that
    buffer, for a socket to read into directly (``filled`` then says how much it read): the
    frame's bytes are not copied again and come in reads of any size, not the caller's buffer's."""

    __slots__ = ("_buffer", "_large", "_filled")

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._large: bytearray | None = None  # a frame larger than what has come, being filled
        self._filled = 0

    def space(self) -> memoryview | None:
        """Where the rest of a large frame goes; None when no large frame is being gathered."""
        return None if self._large is None else memoryview(self._large)[self._filled:]

    def filled(self, size: int) -> list[bytes | bytearray]:
        """``size`` bytes were read into ``space()``: the frame, once it is whole."""
        self._filled += size
        if self._filled < len(self._large):
            return []
        frame, self._large = self._large, None
        return [frame]

    def feed(self, data: bytes) -> list[bytes | bytearray]:
        frames: list[bytes | bytearray] = []
        view = memoryview(data)
        if self._large is not None:
            take = min(len(view), len(self._large) - self._filled)
            self._large[self._filled:self._filled + take] = view[:take]
            self._filled += take
            view = view[take:]
            if self._filled < len(self._large):
                return frames
            frames.append(self._large)  # handed over whole, not copied again
            self._large = None
        buffer = self._buffer
        buffer += view
        start = 0
        while len(buffer) - start >= HEADER:
            size = int.from_bytes(buffer[start:start + HEADER], "little")
            end = start + HEADER + size
            if end <= len(buffer):
                frames.append(bytes(buffer[start + HEADER:end]))
                start = end
                continue
            if size > 1 << 16:  # the rest of a large frame comes straight into its own buffer
                self._large = bytearray(size)
                self._filled = len(buffer) - start - HEADER
                self._large[:self._filled] = buffer[start + HEADER:]
                start = len(buffer)
            break
        del buffer[:start]
        return frames
