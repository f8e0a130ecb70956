"""``LeanConnection``: one HTTP/1.1 keep-alive connection on an asyncio protocol, for load generators.

    async with LeanConnection("http://127.0.0.1:8000", api_key=token) as conn:
        version = await conn.edit(world_id, [edits.sphere((8, 8, 8), 3)])
        block = await conn.read_field(world_id, min_version=version)

It sends the same ``_protocol`` calls as ``AsyncClient`` and reads their answers with the same
parse functions (so the same results and the same errors), but writes the request and reads the
response by hand: httpx spends about twenty times the client CPU per request, which makes a load
generator measure itself. The connection is an ``asyncio.Protocol`` rather than streams: the bytes
collect in one buffer and one future completes when the whole answer is in, so an exchange costs
one wake-up, not one per read call. Plain ``http://`` only; one request at a time per connection
(concurrent callers wait their turn). After a timeout, a broken connection or an unreadable answer
the connection is dropped and the next call opens a fresh one, so a half-read answer is never
taken for the next one.
"""

from __future__ import annotations

import asyncio
import json
import re
from types import MappingProxyType
from typing import Any, Mapping
from urllib.parse import urlencode, urlsplit

import httpx

from sdfclient import _protocol as p
from sdfclient.client import DEFAULT_TIMEOUT_S, _checked_key
from sdfclient.errors import ProtocolError, Timeout, TransportError
from sdfclient.models import Block, QueryResult

HEAD_LIMIT = 1 << 16  # a status line and headers (or a chunk-size line) longer than this are not read
CHUNKED = -1  # _Connection.length of a chunked body
_PLAIN = re.compile(r"[\w.,~-]*", re.ASCII)  # query values sent as they are

Headers = Mapping[str, str]
# status, headers, whether the connection ends after the answer, and the body's length (CHUNKED, or
# None for a body that runs to the end of the connection)
Head = tuple[int, Headers, bool, int | None]
Answer = tuple[int, Headers, bytes, bool]  # status, headers, body, and whether the connection ends
_NO_HEADERS: Headers = MappingProxyType({})


class LeanResponse:
    """The part of ``httpx.Response`` the parse functions read. A real one costs ~100 us to build
    (URL parsing, header normalisation), more than the whole exchange here; ``request`` is built
    only when an error message asks for it."""

    __slots__ = ("status_code", "headers", "content", "_method", "_url")

    def __init__(self, status_code: int, headers: Headers, content: bytes, method: str, url: str):
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
        self._conn: _Connection | None = None
        self._lock = asyncio.Lock()

    async def __aenter__(self) -> "LeanConnection":
        return self

    async def __aexit__(self, *exc_info: Any) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            conn.transport.close()
            await conn.gone

    def _drop(self) -> None:
        if self._conn is not None:
            self._conn.transport.close()
        self._conn = None

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
            target += "?" + _query(kwargs["params"])
        headers = "".join([f"{name}: {value}\r\n" for name, value in kwargs["headers"].items()])
        body = kwargs.get("content", b"")
        if body or call.method not in ("GET", "HEAD", "DELETE"):
            headers += f"content-length: {len(body)}\r\n"
        request = f"{call.method} {target} HTTP/1.1\r\n{self._fixed}{headers}\r\n".encode("latin-1") + body
        timeout = kwargs.get("timeout", self.timeout)
        await self._lock.acquire()  # not `async with`, which adds two coroutines to every exchange
        try:
            conn = self._conn
            # A keep-alive connection the server closed while idle (or that holds bytes nobody asked
            # for) is replaced rather than sent into.
            if conn is None or conn.closed or conn.buffer:
                deadline = asyncio.get_running_loop().time() + timeout
                conn = await self._connect(deadline)
            else:
                deadline = conn.loop.time() + timeout  # not get_running_loop(): a getpid() call each time
            status, headers, content, close = await conn.send(request, call.method, deadline)
            if close:
                self._drop()
        except TimeoutError:
            self._drop()
            raise Timeout(f"{call.method} {call.path}: no answer in {timeout:g} s") from None
        except (OSError, EOFError) as exc:  # refused, reset, or closed mid-answer
            self._drop()
            raise TransportError(f"{call.method} {call.path}: {type(exc).__name__}: {exc}") from exc
        except (ValueError, ProtocolError) as exc:  # an unreadable answer
            self._drop()
            if isinstance(exc, ProtocolError):
                raise
            raise ProtocolError(f"{call.method} {call.path}: {exc}") from exc
        except BaseException:  # cancelled mid-exchange: what is left on the socket is garbage
            self._drop()
            raise
        finally:
            self._lock.release()
        return call.parse(LeanResponse(status, headers, content, call.method, self.base_url + target))

    async def _connect(self, deadline: float) -> _Connection:
        self._drop()
        async with asyncio.timeout_at(deadline):
            _, self._conn = await asyncio.get_running_loop().create_connection(_Connection, self._host, self._port)
        return self._conn


def _query(params: dict[str, str]) -> str:
    # urlencode costs a third of a whole read, and the values of these calls (integers, comma-
    # separated triples, format names) need no quoting: RFC 3986 allows commas in a query, and the
    # server reads "min=1,2,3" as it reads "min=1%2C2%2C3". The names are the protocol's own.
    if _PLAIN.fullmatch("".join(params.values())):
        return "&".join(map("=".join, params.items()))
    return urlencode(params)


class _Connection(asyncio.Protocol):
    """One TCP connection: what arrives collects in ``buffer``, and ``answer`` completes once it holds
    a whole HTTP/1.x response (or fails when the connection breaks or the bytes are not HTTP)."""

    def __init__(self) -> None:
        self.loop = asyncio.get_running_loop()
        self.transport: asyncio.Transport
        self.buffer = bytearray()
        self.closed = False  # the peer sent EOF or the connection is gone: never reused
        self.gone = self.loop.create_future()  # done at connection_lost
        self.answer: asyncio.Future[Answer] | None = None
        self.method = ""
        self.head: Head | None = None  # of the answer being read, once it is in
        self.heads: dict[bytes, Head] = {}  # parsed heads by their bytes
        self.chunks: list[bytes] = []
        self.deadline = 0.0  # of the answer awaited
        self.timer: asyncio.TimerHandle | None = None

    def send(self, request: bytes, method: str, deadline: float) -> asyncio.Future[Answer]:
        """Sends ``request``; its answer fails with TimeoutError at ``deadline``."""
        self.method, self.head, self.chunks = method, None, []
        self.answer = self.loop.create_future()
        # One timer per connection, moved only when it fires before the deadline of the answer then
        # awaited: a timer per exchange (asyncio.timeout sets one too) costs a tenth of the exchange.
        self.deadline = deadline
        if self.timer is None or self.timer.when() > deadline:
            self._set_timer()
        if not self.closed:
            self.transport.write(request)
        if self.buffer or self.closed:  # a fresh connection the server answered or closed at once
            self._advance()
        return self.answer

    def _set_timer(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
        self.timer = self.loop.call_at(self.deadline, self._on_timer)

    def _on_timer(self) -> None:
        armed_for, self.timer = self.timer.when(), None
        if self.answer is None or self.answer.done():
            return  # idle: the next exchange sets a timer again
        if self.deadline <= armed_for:
            self.answer.set_exception(TimeoutError())
        else:
            self._set_timer()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def data_received(self, data: bytes) -> None:
        self.buffer += data
        if self.answer is not None:
            self._advance()

    def eof_received(self) -> None:
        self.closed = True
        if self.answer is not None:
            self._advance()  # the end of a body without a length, or of an answer cut short

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed = True
        if self.timer is not None:
            self.timer.cancel()
        if self.answer is not None and not self.answer.done():
            if exc is None:
                self._advance()
            else:
                self.answer.set_exception(exc)
        if not self.gone.done():
            self.gone.set_result(None)

    def _advance(self) -> None:
        answer = self.answer
        if answer.done():  # timed out already
            return
        try:
            result = self._read()
        except Exception as exc:  # raised in the waiting caller, which maps it
            answer.set_exception(exc)
            return
        if result is not None:
            answer.set_result(result)
        elif self.closed:
            answer.set_exception(EOFError(f"the connection closed mid-answer ({len(self.buffer)} bytes unread)"))

    def _read(self) -> Answer | None:
        """The whole answer, taken out of the buffer; None while it is incomplete."""
        if self.head is None:
            self.head = self._read_head()
            if self.head is None:
                return None
        status, headers, close, length = self.head
        buffer = self.buffer
        if length is None:
            if not self.closed:
                return None
            content, close = bytes(buffer), True
            buffer.clear()
        elif length == CHUNKED:
            content = self._read_chunks()
            if content is None:
                return None
        else:
            if len(buffer) < length:
                return None
            content = bytes(memoryview(buffer)[:length])  # one copy, as StreamReader.readexactly makes
            del buffer[:length]
        return status, headers, content, close

    def _read_head(self) -> Head | None:
        buffer = self.buffer
        while True:
            end = _find(buffer, b"\r\n\r\n", 0, "the answer's head")
            if end < 0:
                return None
            raw = bytes(buffer[:end])
            del buffer[:end + 4]
            # A server's heads repeat (the date changes once a second), and parsing one costs a
            # tenth of the exchange.
            head = self.heads.get(raw)
            if head is None:
                if len(self.heads) >= 16:
                    self.heads.clear()
                head = self.heads[raw] = _parse_head(raw)
            if head[0] >= 200:
                break  # 1xx interim answers (100 Continue) precede the real one
        status, headers, close, length = head
        if length is None and (status in (204, 304) or self.method == "HEAD"):
            return status, headers, close, 0
        return head

    def _read_chunks(self) -> bytes | None:
        """A chunked body, chunk by chunk as each is whole; None until the last one is in."""
        buffer = self.buffer
        while True:
            eol = _find(buffer, b"\r\n", 0, "a chunk-size line")
            if eol < 0:
                return None
            size = int(buffer[:eol].split(b";")[0], 16)
            if size < 0:
                raise ProtocolError(f"negative chunk size {size}")
            if size == 0:
                # Trailers (none that the client reads) end at the first empty line; the size line's
                # own CRLF starts it when there are none.
                end = _find(buffer, b"\r\n\r\n", eol, "the trailers")
                if end < 0:
                    return None
                del buffer[:end + 4]
                return b"".join(self.chunks)
            end = eol + 2 + size
            if len(buffer) < end + 2:
                return None
            if buffer[end:end + 2] != b"\r\n":
                raise ProtocolError("a chunk not followed by CRLF")
            self.chunks.append(bytes(memoryview(buffer)[eol + 2:end]))
            del buffer[:end + 2]


def _find(buffer: bytearray, end: bytes, start: int, what: str) -> int:
    """Where ``end`` starts in ``buffer`` (-1: not in yet), refusing to wait past HEAD_LIMIT bytes."""
    at = buffer.find(end, start)
    if at < 0 and len(buffer) > HEAD_LIMIT:
        raise ProtocolError(f"no end of {what} in {HEAD_LIMIT} bytes")
    return at


def _parse_head(raw: bytes) -> Head:
    lines = raw.decode("latin-1").split("\r\n")
    version, _, rest = lines[0].partition(" ")
    if not version.startswith("HTTP/1."):
        raise ProtocolError(f"not an HTTP/1.x status line: {lines[0][:80]!r}")
    status = int(rest[:3])
    if status < 200:
        return status, _NO_HEADERS, False, None  # an interim answer: only its status is read
    headers: dict[str, str] = {}
    for line in lines[1:]:
        name, sep, value = line.partition(":")
        if not sep:
            raise ProtocolError(f"bad header line {line[:80]!r}")
        name, value = name.strip().lower(), value.strip()
        headers[name] = f"{headers[name]}, {value}" if name in headers else value
    close = "close" in headers.get("connection", "").lower() or version == "HTTP/1.0"
    length: int | None = None  # none given: see _read_head and _read
    if "chunked" in headers.get("transfer-encoding", "").lower():
        length = CHUNKED
    elif "content-length" in headers:
        length = int(headers["content-length"])
        if length < 0:
            raise ProtocolError(f"negative content-length {length}")
    return status, MappingProxyType(headers), close, length  # read-only: shared by the answers with this head
