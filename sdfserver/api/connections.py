"""Limits on connections, enforced before a request's key is checked or its body read.

uvicorn bounds a kept-alive connection's idle time, WebSocket message sizes and queues (its
``Config`` options, set in ``worker.py``), but not how long a client may take to send a request's
headers, how many header bytes it may send (httptools keeps an unfinished header in memory as it
arrives), how many connections a process holds, or which method may ask for a WebSocket
upgrade. ``guarded_protocol`` returns uvicorn's httptools protocol with those four added; it is
handed to uvicorn through its public ``http=`` option (a protocol class), and relies on the
protocol's documented shape in the tested uvicorn range (pyproject.toml).

- **Connections:** past this process's share of ``max_connections`` (HTTP and WebSocket alike:
  uvicorn counts both in one set), a new connection is answered 503 and closed at once, so
  sockets held by idle or slow clients cannot take every file descriptor.
- **Header time:** from the connection's start, or from a kept-alive request's first byte, the
  request line and headers must arrive within ``header_timeout_s``, else 408 and close.
- **Header bytes and lines:** the bytes of an unfinished header are counted as they arrive, and
  a complete one is measured: past ``max_header_bytes`` or ``max_header_count`` lines, 431 and
  close, without reading further.
- **Upgrades:** a WebSocket upgrade must be a GET (RFC 6455); any other method asking for one
  gets 400 rather than a handshake that never answers.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from typing import Any

import httptools
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

log = logging.getLogger("sdfserver.connections")
REASONS = {400: b"Bad Request", 408: b"Request Timeout", 431: b"Request Header Fields Too Large",
           503: b"Service Unavailable"}


@dataclass(frozen=True)
class ConnectionLimits:
    max_connections: int = 4096  # of this process
    max_header_bytes: int = 65536
    max_header_count: int = 100
    header_timeout_s: float = 10.0


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
        if len(self.connections) > self.limits.max_connections:
            self.refuse(503, "this server holds as many connections as it may; try again later")
            return
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


def uvicorn_options(settings: Any, workers: int) -> dict[str, Any]:
    """The ``uvicorn.Config`` options that bound one API process's connections."""
    limits = ConnectionLimits(max_connections=max(1, -(-settings.max_connections // workers)),
                              max_header_bytes=settings.max_header_bytes,
                              max_header_count=settings.max_header_count,
                              header_timeout_s=settings.header_timeout_s)
    ping = settings.ws_ping_interval_s or None
    return {"http": guarded_protocol(limits), "timeout_keep_alive": settings.idle_timeout_s,
            "ws_max_size": settings.max_request_bytes, "ws_max_queue": settings.ws_max_queue,
            "ws_per_message_deflate": settings.ws_deflate, "ws_ping_interval": ping, "ws_ping_timeout": ping}
