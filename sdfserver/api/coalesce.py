"""One write per answer: uvicorn's httptools protocol on a transport that coalesces writes.

uvicorn writes an answer's head and its body with two ``transport.write`` calls, and the
event loop sends each at once: two ``send`` system calls, made with the GIL held, and two
TCP segments, which the client may take in two wake-ups. ``CoalescingHttpToolsProtocol`` hands uvicorn a
transport that keeps the small writes of one event-loop iteration and sends them together
when the iteration's ready callbacks run; large writes (and everything before a close) go
out at once, in order.
"""

from __future__ import annotations

import asyncio
from typing import Any

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

COALESCE_LIMIT_BYTES = 64 << 10  # a write this large goes out at once: flow control sees it


class CoalescingTransport:
    """A transport whose small writes wait for the end of the loop iteration."""

    def __init__(self, transport: asyncio.Transport, loop: asyncio.AbstractEventLoop):
        self.inner = transport  # the socket's own transport
        self._loop = loop
        self._pending: list[bytes] = []

    def write(self, data: bytes) -> None:
        if len(data) >= COALESCE_LIMIT_BYTES:  # now, after what is pending
            self.flush()
            self.inner.write(data)
            return
        if not self._pending:
            self._loop.call_soon(self.flush)
        self._pending.append(bytes(data))

    def writelines(self, lines: Any) -> None:
        for data in lines:
            self.write(data)

    def flush(self) -> None:
        if not self._pending:
            return
        data = self._pending[0] if len(self._pending) == 1 else b"".join(self._pending)
        self._pending = []
        if not self.inner.is_closing():
            self.inner.write(data)

    def get_write_buffer_size(self) -> int:
        return self.inner.get_write_buffer_size() + sum(map(len, self._pending))

    def write_eof(self) -> None:
        self.flush()
        self.inner.write_eof()

    def close(self) -> None:
        self.flush()
        self.inner.close()

    def abort(self) -> None:
        self._pending = []
        self.inner.abort()

    def __getattr__(self, name: str) -> Any:  # is_closing, get_extra_info, pause_reading, ...
        return getattr(self.inner, name)


class CoalescingHttpToolsProtocol(HttpToolsProtocol):
    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(CoalescingTransport(transport, self.loop))  # type: ignore[arg-type]

    def handle_websocket_upgrade(self) -> None:
        # The WebSocket protocol takes over the socket's own transport; nothing is pending then.
        self.transport.flush()
        self.transport = self.transport.inner
        super().handle_websocket_upgrade()
