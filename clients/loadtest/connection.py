"""``Connection``: one keep-alive HTTP/1.1 connection through aiohttp, with ``AsyncClient``'s hot
calls (edit, read_field, read_voxels, query), for the load generator.

It sends the same ``sdfclient._protocol`` calls as ``AsyncClient`` and reads their answers with
the same parse functions (so the same results and the same errors); aiohttp's C parser
(llhttp) costs the load generator a fraction of httpx's CPU per request, so the load test
measures the server rather than itself.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any, Mapping
from urllib.parse import urlsplit

import aiohttp
import httpx

from sdfclient import _protocol as p
from sdfclient.client import DEFAULT_TIMEOUT_S, _checked_key
from sdfclient.errors import ProtocolError, Timeout, TransportError
from sdfclient.models import Block, QueryResult


class Answer:
    """The part of ``httpx.Response`` the parse functions read (a real one costs more to build
    than the exchange); ``request`` is built only when an error message asks for it."""

    __slots__ = ("status_code", "headers", "content", "_method", "_url")

    def __init__(self, status_code: int, headers: Mapping[str, str], content: bytes, method: str, url: str):
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


class HotCalls:
    """What the load test's connections share: the checked base URL, the headers every request
    carries (the API key's among them), the timeout, and ``AsyncClient``'s hot calls, each sent
    through the connection's own ``_send``."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, api_key: str | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S):
        self.url = urlsplit(base_url)
        if self.url.scheme != "http" or not self.url.hostname:
            raise ValueError(f"the load test speaks plain http://host:port only, got {base_url!r}")
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self.headers = {"user-agent": "sdfclient-loadtest"}
        if api_key is not None:
            self.headers["authorization"] = f"Bearer {_checked_key(api_key)}"

    async def __aenter__(self) -> "HotCalls":
        return self

    async def __aexit__(self, *exc_info: Any) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        raise NotImplementedError

    async def _send(self, call: p.Call) -> Any:
        raise NotImplementedError

    async def edit(self, world_id: str, edits: Any) -> int:
        return await self._send(p.edit(world_id, edits))

    async def read_field(self, world_id: str, box: p.BoxArg = None, *, format: str = "distance",  # noqa: A002
                         min_version: int | None = None) -> Block:
        return await self._send(p.read_field(world_id, box, format, min_version, self.timeout))

    async def read_voxels(self, world_id: str, box: p.BoxArg = None, *, min_version: int | None = None) -> Block:
        return await self._send(p.read_voxels(world_id, box, min_version, self.timeout))

    async def query(self, world_id: str, points: Any, *, min_version: int | None = None) -> QueryResult:
        return await self._send(p.query(world_id, points, min_version))


class Connection(HotCalls):
    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, api_key: str | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S):
        super().__init__(base_url, api_key=api_key, timeout=timeout)
        self._session: aiohttp.ClientSession | None = None

    async def aclose(self) -> None:
        session, self._session = self._session, None
        if session is not None:
            await session.close()

    def _session_now(self) -> aiohttp.ClientSession:
        if self._session is None or self._session.closed:
            # one connection, kept alive: the clients of a load test each hold their own
            self._session = aiohttp.ClientSession(
                connector=aiohttp.TCPConnector(limit=1, force_close=False, enable_cleanup_closed=False),
                headers=self.headers, skip_auto_headers=("accept-encoding",), auto_decompress=False)
        return self._session

    async def _send(self, call: p.Call) -> Any:
        kwargs = call.request_kwargs()
        url = self.base_url + call.path
        timeout = kwargs.get("timeout", self.timeout)
        try:
            async with asyncio.timeout(timeout):
                async with self._session_now().request(call.method, url, params=kwargs["params"],
                                                       headers=kwargs["headers"],
                                                       data=kwargs.get("content")) as response:
                    content = await response.read()
                    status, headers = response.status, response.headers
        except TimeoutError:
            await self.aclose()
            raise Timeout(f"{call.method} {call.path}: no answer in {timeout:g} s") from None
        except aiohttp.ClientResponseError as exc:  # an unreadable answer
            await self.aclose()
            raise ProtocolError(f"{call.method} {call.path}: {exc}") from exc
        except (aiohttp.ClientError, OSError) as exc:  # refused, reset, or closed mid-answer
            await self.aclose()
            raise TransportError(f"{call.method} {call.path}: {type(exc).__name__}: {exc}") from exc
        return call.parse(Answer(status, headers, content, call.method, url))
