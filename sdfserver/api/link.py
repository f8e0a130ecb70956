"""The link between the server process and one front process: length-prefixed pickles over a
Unix socket pair, and connections handed from the front to the server.

Both ends belong to one ``sdfserver serve``: the pair is made by the server process before it
starts the front, so nothing else can write to it, and pickle (engine commands, numpy arrays)
is safe there. A frame is a length-prefixed pickle of a list of messages. The front's end is
``LinkProtocol`` on its event loop: its messages of one loop iteration leave in one frame. The
server's end is threads (``desklink.py``).

A handed-over connection travels on a second pair (``SOCK_SEQPACKET``): its socket as
``SCM_RIGHTS``, with the bytes the front already read from it, in parts of at most
``PART_BYTES``; the first byte of each part says whether more follow.
"""

from __future__ import annotations

import asyncio
import collections
import pickle
import socket
import struct
from typing import Any, Callable

HEADER = struct.Struct("<I")
PART_BYTES = 60 << 10  # below a Unix socket's default send buffer, so any part fits in one message
MORE, LAST = b"\x01", b"\x00"


class LinkProtocol(asyncio.Protocol):
    def __init__(self, on_message: Callable[[Any], None], on_lost: Callable[[], None] = lambda: None):
        self.on_message, self.on_lost = on_message, on_lost
        self.transport: asyncio.Transport | None = None
        self._buffer = bytearray()
        self._outgoing: collections.deque[Any] = collections.deque()
        self._flush_scheduled = False
        self._loop = asyncio.get_running_loop()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def connection_lost(self, exc: Exception | None) -> None:
        self.transport = None
        self.on_lost()

    def data_received(self, data: bytes) -> None:
        self._buffer += data
        take_frames(self._buffer, self.on_message)

    def send(self, message: Any) -> None:
        """Queue ``message``; it leaves with the others of this loop iteration (loop thread)."""
        self._outgoing.append(message)
        if not self._flush_scheduled:
            self._flush_scheduled = True
            self._loop.call_soon(self._flush)

    def _flush(self) -> None:
        self._flush_scheduled = False
        if not self._outgoing:
            return
        messages, self._outgoing = list(self._outgoing), collections.deque()
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(frame(messages))


def frame(messages: list[Any]) -> bytes:
    """One frame for several messages: one pickle looks each class up once for all of them
    (unpickling eight edit commands together costs a third of unpickling them one by one)."""
    payload = pickle.dumps(messages, protocol=5)
    return HEADER.pack(len(payload)) + payload


def take_frames(buffer: bytearray, on_message: Callable[[Any], None]) -> None:
    """Hand on the messages of each whole frame at the start of ``buffer``; leave a partial one there."""
    start = 0
    while len(buffer) - start >= HEADER.size:
        (size,) = HEADER.unpack_from(buffer, start)
        end = start + HEADER.size + size
        if end > len(buffer):
            break
        messages = pickle.loads(memoryview(buffer)[start + HEADER.size:end])
        start = end
        for message in messages:
            on_message(message)
    del buffer[:start]


def handoff_pair() -> tuple[socket.socket, socket.socket]:
    return socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)


def send_connection(channel: socket.socket, connection: socket.socket, data: bytes) -> None:
    """Hand ``connection`` over, with ``data`` already read from it (blocking; small)."""
    parts = [data[i:i + PART_BYTES] for i in range(0, len(data), PART_BYTES)] or [b""]
    for i, part in enumerate(parts):
        flag = LAST if i == len(parts) - 1 else MORE
        socket.send_fds(channel, [flag + part], [connection.fileno()] if i == 0 else [])


class ConnectionReceiver:
    """Reassembles handed-over connections from a handoff channel (non-blocking reads)."""

    def __init__(self, channel: socket.socket):
        self.channel = channel
        self._connection: socket.socket | None = None
        self._parts: list[bytes] = []

    def receive(self) -> tuple[socket.socket, bytes] | None | bool:
        """A complete (connection, data); None if more is to come; False at end of file."""
        try:
            message, fds, flags, _ = socket.recv_fds(self.channel, PART_BYTES + 1, 1)
        except BlockingIOError:
            return None
        if not message and not fds:
            return False
        for fd in fds:
            if self._connection is not None:  # a new one before the last was complete: never sent so
                self._connection.close()
            self._connection, self._parts = socket.socket(fileno=fd), []
        if self._connection is None or flags & (socket.MSG_TRUNC | socket.MSG_CTRUNC):
            raise ConnectionError("a malformed connection hand-over on the front link")
        self._parts.append(message[1:])
        if message[:1] == MORE:
            return None
        connection, self._connection = self._connection, None
        return connection, b"".join(self._parts)


def reuseport_socket(host: str, port: int) -> socket.socket:
    """A TCP socket bound to (host, port) with SO_REUSEPORT: every front binds one and listens;
    the kernel spreads the connections over them. The server process binds one without listening,
    which holds the port (and picks it, for port 0) while the fronts come and go."""
    family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    sock.bind(address)
    return sock
