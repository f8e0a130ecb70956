"""The engine's stream sockets: addresses, length-prefixed frames, and a reader that cuts a byte
stream back into frames.

An engine listens at two addresses (``ipc:///path``: a Unix socket on this machine;
``tcp://host:port``: TCP, for engines on other machines). Every message is one frame: a 4-byte
little-endian length, then that many bytes (a msgspec-encoded message). The first frames on a
connection are the connecting API process's proof and identity (``links.py``). A plain
stream socket is one thread wake per hop where a ZeroMQ socket is three (its I/O thread on each
side, then the reader), and that hop sits twice in every request.

A reader takes frames up to a limit its owner sets (``links.LinkLimits``): a header announcing
more ends the connection before a byte of buffer is set aside for it, so a peer cannot make
either end hold memory for a frame it never sends.
"""

from __future__ import annotations

import os
import socket
import stat
from typing import Any, Callable
from urllib.parse import urlsplit

HEADER = 4
MAX_FRAME = 2**32 - 1
# A Unix socket's sender may have this much in flight (the system caps it at twice
# net.core.wmem_max): a megabyte query or answer is written in one call and read in a few,
# where the default (about 200 KiB) makes writer and reader take turns, a thread wake each.
UNIX_SEND_BUFFER = 4 << 20


class FrameTooLarge(ValueError):
    """A frame past a link's limit: announced by a header (the connection must end) or about to
    be sent."""


def frame(payload: bytes) -> bytes:
    if len(payload) > MAX_FRAME:
        raise FrameTooLarge(f"a message of {len(payload)} bytes passes the {MAX_FRAME}-byte frame limit")
    return len(payload).to_bytes(HEADER, "little") + payload


def encode_frame(encode_into: Callable[[Any, bytearray, int], None], message: Any,
                 limit: int = MAX_FRAME) -> bytearray:
    """``message`` encoded straight after its frame's header (``encode_into``: a msgspec
    encoder's): a megabyte message is copied once, not again to put the header before it.
    FrameTooLarge when it passes ``limit`` bytes (at most MAX_FRAME)."""
    data = bytearray(HEADER)
    encode_into(message, data, HEADER)
    size = len(data) - HEADER
    if size > min(limit, MAX_FRAME):
        raise FrameTooLarge(f"a message of {size} bytes passes the link's limit of {min(limit, MAX_FRAME)} bytes")
    data[:HEADER] = size.to_bytes(HEADER, "little")
    return data


def family_and_target(address: str) -> tuple[int, str | tuple[str, int]]:
    url = urlsplit(address)
    if url.scheme == "ipc":
        return socket.AF_UNIX, url.path
    if url.scheme == "tcp" and url.hostname and url.port:
        return socket.AF_INET, (url.hostname, url.port)
    raise ValueError(f"an engine address is ipc:///path or tcp://host:port, got {address!r}")


def check_private(directory: str) -> None:
    """A Unix socket's connections prove nothing (``links.py``): only its directory's permissions
    keep other users out, so the directory must be this user's and closed to everyone else."""
    info = os.stat(directory)
    if info.st_uid != os.getuid() or info.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise PermissionError(f"an engine's Unix socket must live in a directory only this user can open "
                              f"(mode 0700, owned by uid {os.getuid()}); {directory} has mode "
                              f"{stat.S_IMODE(info.st_mode):04o} and owner {info.st_uid}")


def listen(address: str) -> socket.socket:
    family, target = family_and_target(address)
    if family == socket.AF_UNIX:
        check_private(os.path.dirname(target) or ".")
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
    frame's bytes are not copied again and come in reads of any size, not the caller's buffer's.

    ``limit`` is the largest frame taken: ``feed`` raises FrameTooLarge for a header announcing
    more, before anything is allocated for it. Its owner may change it between frames (a link
    that has proven itself may send larger ones). Every link sets its own (``links.py``); the
    default is only the wire format's bound."""

    __slots__ = ("_buffer", "_large", "_filled", "limit")

    def __init__(self, limit: int = MAX_FRAME) -> None:
        self.limit = limit
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

    def feed(self, data: bytes, most: int | None = None) -> list[bytes | bytearray]:
        """The frames ``data`` completes; with ``most``, no more than that many, the rest kept
        for the next call (its limit may have changed by then)."""
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
        while len(buffer) - start >= HEADER and (most is None or len(frames) < most):
            size = int.from_bytes(buffer[start:start + HEADER], "little")
            if size > self.limit:
                raise FrameTooLarge(f"a frame of {size} bytes was announced; this link takes at most {self.limit}")
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
