"""Limits on connections, enforced before a request's key is checked or its body read.

uvicorn bounds a kept-alive connection's idle time, WebSocket message sizes and queues (its
``Config`` options, set in ``worker.py``), but not how long a client may take to send a request's
headers, how many header bytes it may send (httptools keeps an unfinished header in memory as it
arrives), how many connections a process holds, which method may ask for a WebSocket upgrade, or
how long a WebSocket peer may leave what is sent to it unread. ``guarded_protocol`` returns
uvicorn's httptools protocol with the first four added, ``guarded_websocket_protocol`` its
WebSocket protocol with the last; they are handed to uvicorn through its public ``http=`` and
``ws=`` options (protocol classes), and rely on the protocols' documented shape in the tested
uvicorn range (pyproject.toml).

- **Connections** (``connection_limits``, enforced by ``port.Listener`` as it accepts): past this
  process's share of ``max_connections`` (HTTP and WebSocket alike: uvicorn counts both in one
  set), or past what its file-descriptor limit leaves room for, a new connection is answered 503
  and closed at once, so that sockets held by idle or slow clients cannot take every descriptor.
- **Header time:** from the connection's start, or from a kept-alive request's first byte, the
  request line and headers must arrive within ``header_timeout_s``, else 408 and close.
- **Header bytes and lines:** the bytes of an unfinished header are counted as they arrive, and
  a complete one is measured: past ``max_header_bytes`` or ``max_header_count`` lines, 431 and
  close, without reading further.
- **Upgrades:** a WebSocket upgrade must be a GET (RFC 6455); any other method asking for one
  gets 400 rather than a handshake that never answers.
- **WebSocket peers that stop reading:** while bytes wait for a peer that takes none of them for
  ``ws_send_timeout_s`` (its socket buffers full), the connection is aborted, counted and
  logged. Without this nothing ends it: the app's send waits for the transport to drain, the
  ping timeout's close waits for the same, and each such peer pins megabytes of socket buffers.
"""

from __future__ import annotations

import asyncio
import fcntl
import logging
import resource
import struct
import termios
from dataclasses import dataclass
from typing import Any

import httptools
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

from sdfserver.api.counts import SharedCounts, ThrottledLog

log = logging.getLogger("sdfserver.connections")
# Descriptors an API process keeps for what is not a client's connection: the listening socket,
# its engines' sockets, the event loop's own, log and library files, and a 503 to a refused client.
RESERVED_DESCRIPTORS = 64
REASONS = {400: b"Bad Request", 408: b"Request Timeout", 431: b"Request Header Fields Too Large"}


@dataclass(frozen=True)
class ConnectionLimits:
    max_connections: int = 4096  # of this process
    max_header_bytes: int = 65536
    max_header_count: int = 100
    header_timeout_s: float = 10.0
    capped_by_descriptors: bool = False  # max_connections is what the descriptor limit leaves room for


class HeadersTooLarge(Exception):
    pass


def guarded_protocol(limits: ConnectionLimits) -> type[HttpToolsProtocol]:
    """uvicorn's httptools protocol with ``limits`` (a class, as uvicorn's ``http=`` takes)."""
    return type("GuardedHttpProtocol", (GuardedHttpProtocol,), {"limits": limits})


class GuardedHttpProtocol(HttpToolsProtocol):
    limits = ConnectionLimits()
    header_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self.header_bytes = self.header_lines = self.header_size = 0  # as arrived; lines; as parsed
        self.reading_headers = True
        self.arm_header_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self.disarm_header_timer()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self.transport.is_closing():
            return
        if self.reading_headers:
            self.header_bytes += len(data)
        self._unset_keepalive_if_required()
        try:
            self.parser.feed_data(data)
        except httptools.HttpParserUpgrade:
            if self._should_upgrade():
                self.handle_websocket_upgrade()
            else:
                self._unsupported_upgrade_warning()
            return
        except httptools.HttpParserError as exc:
            if isinstance(exc.__context__, HeadersTooLarge):
                self.refuse(431, str(exc.__context__))
            else:
                log.warning("invalid HTTP request received")
                self.refuse(400, "Invalid HTTP request received.")
            return
        if self.reading_headers:  # a request's headers began and did not end in this piece
            if self.header_bytes > self.limits.max_header_bytes:
                self.refuse(431, f"request headers exceed {self.limits.max_header_bytes} bytes")
            elif self.header_timer is None:
                self.arm_header_timer()

    # the parser's callbacks, in the order it calls them for each request
    def on_message_begin(self) -> None:
        super().on_message_begin()
        if not self.reading_headers:  # a kept-alive connection's next request: its timer is armed
            self.reading_headers = True  # when a piece ends with its headers unfinished, which the
            self.header_bytes = self.header_lines = self.header_size = 0  # usual request never is

    def on_url(self, url: bytes) -> None:
        self.count_header_bytes(len(url))
        super().on_url(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        self.header_lines += 1
        if self.header_lines > self.limits.max_header_count:
            raise HeadersTooLarge(f"more than {self.limits.max_header_count} header lines")
        self.count_header_bytes(len(name) + len(value) + 4)
        super().on_header(name, value)

    def on_headers_complete(self) -> None:
        self.reading_headers = False
        if self.header_timer is not None:
            self.disarm_header_timer()
        super().on_headers_complete()

    def handle_websocket_upgrade(self) -> None:
        if self.scope.get("method") != "GET":
            self.refuse(400, "a WebSocket upgrade must be a GET request")
            return
        self.disarm_header_timer()
        super().handle_websocket_upgrade()

    # -- the limits ---------------------------------------------------------------------------

    def count_header_bytes(self, n: int) -> None:
        self.header_size += n
        if self.header_size > self.limits.max_header_bytes:
            raise HeadersTooLarge(f"request headers exceed {self.limits.max_header_bytes} bytes")

    def arm_header_timer(self) -> None:
        self.disarm_header_timer()
        self.header_timer = self.loop.call_later(self.limits.header_timeout_s, self.headers_too_slow)

    def disarm_header_timer(self) -> None:
        if self.header_timer is not None:
            self.header_timer.cancel()
            self.header_timer = None

    def headers_too_slow(self) -> None:
        self.header_timer = None
        if self.reading_headers and not self.transport.is_closing():
            self.refuse(408, f"the request's headers did not arrive within {self.limits.header_timeout_s:g} s")

    def refuse(self, status: int, message: str) -> None:
        """Answer ``status`` with ``message`` and close, reading nothing more."""
        self.disarm_header_timer()
        self.reading_headers = False
        body = message.encode()
        head = [b"HTTP/1.1 %d %s\r\n" % (status, REASONS[status]),
                *(name + b": " + value + b"\r\n" for name, value in self.server_state.default_headers),
                b"content-type: text/plain; charset=utf-8\r\n",
                b"content-length: %d\r\n" % len(body), b"connection: close\r\n\r\n"]
        if not self.transport.is_closing():
            self.transport.write(b"".join(head) + body)
            self.transport.close()


def guarded_websocket_protocol(send_timeout_s: float, counts: SharedCounts) -> type[WebSocketsSansIOProtocol]:
    """uvicorn's WebSocket protocol that aborts a peer that stops reading (a class, as ``ws=`` takes)."""
    return type("GuardedWebSocketProtocol", (GuardedWebSocketProtocol,),
                {"send_timeout_s": send_timeout_s, "counts": counts, "stalls": ThrottledLog(log)})


class GuardedWebSocketProtocol(WebSocketsSansIOProtocol):
    """Bytes wait for the peer while the transport is over its high-water mark (the app's sends
    wait then) or closing (a close waits for them to drain). In both states nothing new is
    written but control frames, so if the bytes waiting — in the transport and in the socket's
    send queue, not yet acknowledged by the peer — have not gone down in ``send_timeout_s``, the
    peer took nothing: it is aborted, since ``close()`` would wait for it forever. A reader that
    is slow but reads acknowledges something every little while and stays."""

    send_timeout_s = 30.0  # 0: never
    counts = SharedCounts()
    stalls = ThrottledLog(log)
    watch_timer: asyncio.TimerHandle | None = None
    stalled: tuple[float, int] | None = None  # (since, bytes waiting then) while bytes wait

    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        self.watch()

    def connection_lost(self, exc: Exception | None) -> None:
        if self.watch_timer is not None:
            self.watch_timer.cancel()
            self.watch_timer = None
        super().connection_lost(exc)

    def handle_ping(self) -> None:
        if not self.writable.is_set():  # the peer is not reading: its pongs would only pile up here
            self.conn.data_to_send()
            return
        super().handle_ping()

    def watch(self) -> None:
        if self.send_timeout_s > 0:  # looked at twice a timeout: a stall is seen within 1.5 timeouts
            self.watch_timer = self.loop.call_later(self.send_timeout_s / 2, self.check_peer_reads)

    def check_peer_reads(self) -> None:
        self.watch_timer = None
        waiting = self.transport.get_write_buffer_size() + unacknowledged_bytes(self.transport)
        now = self.loop.time()
        if waiting == 0 or (self.writable.is_set() and not self.transport.is_closing()):
            self.stalled = None
        elif self.stalled is None or waiting < self.stalled[1]:
            self.stalled = (now, waiting)  # the peer took some: the wait starts again
        elif now - self.stalled[0] >= self.send_timeout_s:
            self.counts.add("websocket_send_timeouts")
            client = "%s:%d" % self.client if self.client else "a client"
            self.stalls.warning("closing the WebSocket of %s: it took none of the %d bytes waiting for it in "
                                "%.0f s (ws_send_timeout_s)", client, waiting, now - self.stalled[0])
            self.transport.abort()
            return
        self.watch()


def unacknowledged_bytes(transport: Any) -> int:
    """Bytes in the socket's send queue that the peer has not acknowledged (Linux's SIOCOUTQ);
    0 where that cannot be asked. Unlike the transport's buffer, which the kernel refills only
    once a third of a (megabytes) send buffer is free, it goes down as soon as the peer reads."""
    sock = transport.get_extra_info("socket")
    if sock is None or not hasattr(termios, "TIOCOUTQ"):
        return 0
    try:
        return struct.unpack("i", fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0" * 4))[0]
    except OSError:  # closed meanwhile, or not a socket that keeps a send queue
        return 0


def descriptor_limit() -> int | None:
    """This process's soft RLIMIT_NOFILE, or None where there is none."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    return None if soft == resource.RLIM_INFINITY else soft


def connection_limits(settings: Any, workers: int) -> ConnectionLimits:
    """One API process's limits: its share of ``max_connections``, or fewer where its
    file-descriptor limit leaves room for fewer (then refusals say so)."""
    share = max(1, -(-settings.max_connections // workers))
    limit = descriptor_limit()
    room = share if limit is None else max(1, limit - RESERVED_DESCRIPTORS)
    return ConnectionLimits(max_connections=min(share, room), max_header_bytes=settings.max_header_bytes,
                            max_header_count=settings.max_header_count, header_timeout_s=settings.header_timeout_s,
                            capped_by_descriptors=room < share)


def say_descriptor_room(settings: Any, workers: int) -> None:
    """A warning at start-up where the descriptor limit leaves an API process room for fewer
    connections than its share of ``max_connections``."""
    limits = connection_limits(settings, workers)
    if limits.capped_by_descriptors:
        log.warning("the file-descriptor limit (%d) leaves each API process room for %d connections, fewer than "
                    "its share of max_connections (%d): those past it are answered 503; raise LimitNOFILE "
                    "(ulimit -n)", descriptor_limit(), limits.max_connections,
                    -(-settings.max_connections // workers))


def uvicorn_options(settings: Any, workers: int, counts: SharedCounts) -> dict[str, Any]:
    """The ``uvicorn.Config`` options that bound one API process's connections."""
    ping = settings.ws_ping_interval_s or None
    return {"http": guarded_protocol(connection_limits(settings, workers)),
            "ws": guarded_websocket_protocol(settings.ws_send_timeout_s, counts),
            "timeout_keep_alive": settings.idle_timeout_s,
            "ws_max_size": settings.max_request_bytes, "ws_max_queue": settings.ws_max_queue,
            "ws_per_message_deflate": settings.ws_deflate, "ws_ping_interval": ping, "ws_ping_timeout": ping}
