"""``ParsedConnection``: one keep-alive HTTP/1.1 connection on an asyncio protocol, its answers
read by httptools' parser (the one uvicorn serves with), with ``Connection``'s hot calls.

It makes the same calls as ``Connection`` (``HotCalls``) and reads their answers with the same
parse functions (so the same results and errors), without a client session, its
connector and its response objects around each exchange: a lone client's latency is more the
server's and less the load generator's own.
"""

from __future__ import annotations

import asyncio
from typing import Any
from urllib.parse import urlencode

import httptools

from loadtest.connection import Answer, HotCalls
from sdfclient import _protocol as p
from sdfclient.client import DEFAULT_TIMEOUT_S
from sdfclient.errors import ProtocolError, Timeout, TransportError


class _Exchange(asyncio.Protocol):
    """Answers arriving on the connection, one at a time (requests are never pipelined)."""

    def __init__(self) -> None:
        self.transport: asyncio.Transport | None = None
        self.parser = httptools.HttpResponseParser(self)
        self.waiting: asyncio.Future | None = None
        self.headers: dict[str, str] = {}
        self.body: list[bytes] = []

    def connection_made(self, transport: Any) -> None:
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        try:
            self.parser.feed_data(data)
        except httptools.HttpParserError as exc:
            self._end(ProtocolError(f"an unreadable answer: {exc}"))

    def connection_lost(self, exc: Exception | None) -> None:
        self.transport = None
        self._end(TransportError(f"the server closed the connection{f': {exc}' if exc else ''}"))

    def on_header(self, name: bytes, value: bytes) -> None:
        self.headers[name.decode("latin-1").lower()] = value.decode("latin-1")

    def on_body(self, body: bytes) -> None:
        self.body.append(body)

    def on_message_complete(self) -> None:
        if self.waiting is not None and not self.waiting.done():
            self.waiting.set_result((self.parser.get_status_code(), self.headers, b"".join(self.body)))
        self.headers, self.body = {}, []

    def _end(self, exc: Exception) -> None:
        if self.waiting is not None and not self.waiting.done():
            self.waiting.set_exception(exc)


class ParsedConnection(HotCalls):
    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, api_key: str | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S):
        super().__init__(base_url, api_key=api_key, timeout=timeout)
        self.host, self.port = self.url.hostname, self.url.port or 80
        self._fixed = "\r\n".join([f"host: {self.url.netloc}", *(f"{k}: {v}" for k, v in self.headers.items())])
        self._exchange: _Exchange | None = None

    async def aclose(self) -> None:
        exchange, self._exchange = self._exchange, None
        if exchange is not None and exchange.transport is not None:
            exchange.transport.close()

    async def _connected(self) -> _Exchange:
        if self._exchange is None or self._exchange.transport is None:
            _, self._exchange = await asyncio.get_running_loop().create_connection(_Exchange, self.host, self.port)
        return self._exchange

    async def _send(self, call: p.Call) -> Any:
        kwargs = call.request_kwargs()
        target = call.path + (f"?{urlencode(kwargs['params'])}" if kwargs["params"] else "")
        body = kwargs.get("content") or b""
        head = [f"{call.method} {target} HTTP/1.1", self._fixed, f"content-length: {len(body)}"]
        head += [f"{name}: {value}" for name, value in kwargs["headers"].items()]
        timeout = kwargs.get("timeout", self.timeout)
        try:
            async with asyncio.timeout(timeout):
                exchange = await self._connected()
                exchange.waiting = asyncio.get_running_loop().create_future()
                exchange.transport.write(("\r\n".join(head) + "\r\n\r\n").encode("latin-1") + body)
                status, headers, content = await exchange.waiting
        except TimeoutError:
            await self.aclose()
            raise Timeout(f"{call.method} {call.path}: no answer in {timeout:g} s") from None
        except (ProtocolError, TransportError, OSError) as exc:
            await self.aclose()
            if isinstance(exc, OSError):
                raise TransportError(f"{call.method} {call.path}: {type(exc).__name__}: {exc}") from exc
            raise
        if headers.get("connection", "").lower() == "close":
            await self.aclose()
        return call.parse(Answer(status, headers, content, call.method, self.base_url + call.path))
