"""``LeanConnection``: one HTTP/1.1 keep-alive connection over asyncio streams, for load generators.

    async with LeanConnection("http://127.0.0.1:8000", api_key=token) as conn:
        version = await conn.edit(world_id, [edits.sphere((8, 8, 8), 3)])
        block = await conn.read_field(world_id, min_version=version)

It sends the same ``_protocol`` calls as ``AsyncClient`` and reads their answers with the same
parse functions (so the same results and the same errors), but writes the request and reads the
response by hand: httpx spends about ten times the client CPU per request, which makes a load
generator measure itself. Plain ``http://`` only; one request at a time per connection (concurrent
callers wait their turn). After a timeout, a broken connection or an unreadable answer the
connection is dropped and the next call opens a fresh one, so a half-read answer is never taken
for the next one.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any
from urllib.parse import urlencode, urlsplit

import httpx

from sdfclient import _protocol as p
from sdfclient.client import DEFAULT_TIMEOUT_S, _checked_key
from sdfclient.errors import ProtocolError, Timeout, TransportError
from sdfclient.models import Block, QueryResult


class LeanResponse:
    """The part of ``httpx.Response`` the parse functions read. A real one costs ~100 us to build
    (URL parsing, header normalisation), more than the whole exchange here; ``request`` is built
    only when an error message asks for it."""

    __slots__ = ("status_code", "headers", "content", "_method", "_url")

    def __init__(self, status_code: int, headers: dict[str, str], content: bytes, method: str, url: str):
        self.status_code, self.headers, self.content = status_code, headers, content
        self._method, self._url = method, url

    @property
    def text(self) -> str:
        return self.content.decode("utf-8", "replace")

    def json(self) -> Any:
        return json.loads(self.content)

    @property
    def request(self) -> httpx.Request:
        return httpx.Request(self._method, self._url)


class LeanConnection:
    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, api_key: str | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S):
        url = urlsplit(base_url)
        if url.scheme != "http" or not url.hostname:
            raise ValueError(f"LeanConnection speaks plain http://host:port only, got {base_url!r}")
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self._host, self._port, self._prefix = url.hostname, url.port or 80, url.path.rstrip("/")
        auth = "" if api_key is None else f"authorization: Bearer {_checked_key(api_key)}\r\n"
        self._fixed = f"host: {url.netloc}\r\nuser-agent: sdfclient-lean\r\n{auth}"
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lock = asyncio.Lock()

    async def __aenter__(self) -> "LeanConnection":
        return self

    async def __aexit__(self, *exc_info: Any) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        writer, self._reader, self._writer = self._writer, None, None
        if writer is not None:
            writer.close()
            try:
                await writer.wait_closed()
            except OSError:
                pass  # the peer had already gone

    def _drop(self) -> None:
        if self._writer is not None:
            self._writer.close()
        self._reader = self._writer = None

    async def edit(self, world_id: str, edits: Any) -> int:
        return await self._send(p.edit(world_id, edits))

    async def read_field(self, world_id: str, box: p.BoxArg = None, *, format: str = "distance",  # noqa: A002
                         min_version: int | None = None) -> Block:
        return await self._send(p.read_field(world_id, box, format, min_version, self.timeout))

    async def read_voxels(self, world_id: str, box: p.BoxArg = None, *, min_version: int | None = None) -> Block:
        return await self._send(p.read_voxels(world_id, box, min_version, self.timeout))

    async def query(self, world_id: str, points: Any, *, min_version: int | None = None) -> QueryResult:
        return await self._send(p.query(world_id, points, min_version))

    async def _send(self, call: p.Call) -> Any:
        kwargs = call.request_kwargs()
        target = self._prefix + call.path
        if kwargs["params"]:
            target += "?" + urlencode(kwargs["params"])
        head = f"{call.method} {target} HTTP/1.1\r\n{self._fixed}"
        head += "".join(f"{name}: {value}\r\n" for name, value in kwargs["headers"].items())
        body = kwargs.get("content", b"")
        if body or call.method not in ("GET", "HEAD", "DELETE"):
            head += f"content-length: {len(body)}\r\n"
        request = (head + "\r\n").encode("latin-1") + body
        timeout = kwargs.get("timeout", self.timeout)
        what = f"{call.method} {call.path}"
        async with self._lock:
            try:
                # asyncio.timeout, not wait_for: on 3.11 wait_for wraps the exchange in a new task.
                async with asyncio.timeout(timeout):
                    status, headers, content = await self._exchange(request, call.method)
            except TimeoutError:
                self._drop()
                raise Timeout(f"{what}: no answer in {timeout:g} s") from None
            except (OSError, EOFError) as exc:  # refused, reset, or closed mid-answer
                self._drop()
                raise TransportError(f"{what}: {type(exc).__name__}: {exc}") from exc
            except (ValueError, asyncio.LimitOverrunError, ProtocolError) as exc:  # an unreadable answer
                self._drop()
                raise exc if isinstance(exc, ProtocolError) else ProtocolError(f"{what}: {exc}") from exc
            except BaseException:  # cancelled mid-exchange: what is left on the socket is garbage
                self._drop()
                raise
        return call.parse(LeanResponse(status, headers, content, call.method, self.base_url + target))

    async def _exchange(self, request: bytes, method: str) -> tuple[int, dict[str, str], bytes]:
        # A keep-alive connection the server closed while idle shows EOF here: reconnect rather than
        # send into it.
        if self._writer is None or self._reader.at_eof():
            self._drop()
            self._reader, self._writer = await asyncio.open_connection(self._host, self._port)
        reader, writer = self._reader, self._writer
        writer.write(request)
        await writer.drain()
        while True:
            lines = (await reader.readuntil(b"\r\n\r\n")).decode("latin-1").split("\r\n")
            version, _, rest = lines[0].partition(" ")
            if not version.startswith("HTTP/1."):
                raise ProtocolError(f"not an HTTP/1.x status line: {lines[0][:80]!r}")
            status = int(rest[:3])
            if status >= 200:
                break  # 1xx interim answers (100 Continue) precede the real one
        headers: dict[str, str] = {}
        for line in lines[1:-2]:
            name, sep, value = line.partition(":")
            if not sep:
                raise ProtocolError(f"bad header line {line[:80]!r}")
            name, value = name.strip().lower(), value.strip()
            headers[name] = f"{headers[name]}, {value}" if name in headers else value
        close = "close" in headers.get("connection", "").lower() or version == "HTTP/1.0"
        if "chunked" in headers.get("transfer-encoding", "").lower():
            content = await _read_chunked(reader)
        elif "content-length" in headers:
            content = await reader.readexactly(int(headers["content-length"]))
        elif status in (204, 304) or method == "HEAD":
            content = b""
        else:  # no length: the body runs to the end of the connection
            content, close = await reader.read(), True
        if close:
            self._drop()
        return status, headers, content


async def _read_chunked(reader: asyncio.StreamReader) -> bytes:
    parts = []
    while True:
        size = int((await reader.readuntil(b"\r\n")).split(b";")[0], 16)
        if size == 0:
            while await reader.readuntil(b"\r\n") != b"\r\n":
                pass  # trailers: none that the client reads
            return b"".join(parts)
        chunk = await reader.readexactly(size + 2)
        if chunk[-2:] != b"\r\n":
            raise ProtocolError("a chunk not followed by CRLF")
        parts.append(chunk[:-2])
