"""``Client`` and ``AsyncClient``: the HTTP API of sdfserver, in the httpx shape.

    with Client("http://127.0.0.1:8000") as client:
        world = client.create_world(size=(64, 64, 64))
        version = client.edit(world.id, [sphere((32, 32, 32), 6)])
        field = client.read_field(world.id, min_version=version)   # reads its own write

Both take an injectable ``transport`` (``httpx.MockTransport``,
``httpx.ASGITransport``, ...) for tests; both are context managers. The two
classes differ only in how they send a call: what is sent and how the answer
is read live in ``_protocol``.
"""

from __future__ import annotations

from typing import Any, Sequence

import httpx

from sdfclient import _protocol as p
from sdfclient.errors import Timeout, TransportError
from sdfclient.models import Block, QueryResult, WorldInfo

DEFAULT_TIMEOUT_S = 30.0


def _transport_error(exc: httpx.TransportError, call: p.Call) -> TransportError:
    cls = Timeout if isinstance(exc, httpx.TimeoutException) else TransportError
    return cls(f"{call.method} {call.path}: {type(exc).__name__}: {exc}")


def _options(base_url: str, timeout: float, headers: dict | None) -> dict:
    return {"base_url": base_url.rstrip("/"), "timeout": timeout,
            "headers": {"user-agent": "sdfclient", **(headers or {})}}


class Client:
    """A blocking client. Thread-safe as httpx.Client is; one per thread is simplest."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, timeout: float = DEFAULT_TIMEOUT_S,
                 transport: httpx.BaseTransport | None = None, headers: dict | None = None):
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self._http = httpx.Client(transport=transport, **_options(base_url, timeout, headers))

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _send(self, call: p.Call) -> Any:
        try:
            response = self._http.request(call.method, call.path, **call.request_kwargs())
        except httpx.TransportError as exc:
            raise _transport_error(exc, call) from exc
        return call.parse(response)

    # -- worlds ---------------------------------------------------------------------------------

    def create_world(self, size: Sequence[int], *, chunk_size: int = 16, max_distance: int = 255,
                     algorithm: str = "exact", focus: Any = None) -> WorldInfo:
        return self._send(p.create_world(size, chunk_size, max_distance, algorithm, focus))

    def list_worlds(self) -> list[WorldInfo]:
        return self._send(p.list_worlds())

    def get_world(self, world_id: str) -> WorldInfo:
        return self._send(p.get_world(world_id))

    def update_world(self, world_id: str, *, algorithm: Any = p.KEEP, focus: Any = p.KEEP,
                     max_distance: Any = p.KEEP) -> WorldInfo:
        """PATCH the named settings; ``focus=None`` removes the focus."""
        return self._send(p.update_world(world_id, algorithm, focus, max_distance))

    def delete_world(self, world_id: str) -> None:
        self._send(p.delete_world(world_id))

    # -- edits and reads --------------------------------------------------------------------------

    def edit(self, world_id: str, edits: Any) -> int:
        """Send one atomic batch (see ``sdfclient.edits``); returns the world's new version."""
        return self._send(p.edit(world_id, edits))

    def read_field(self, world_id: str, box: p.BoxArg = None, *, format: str = "distance",  # noqa: A002
                   min_version: int | None = None) -> Block:
        """The field of ``box`` (``(min, max)``, max exclusive; None: the whole world).

        With ``min_version`` the server waits (bounded) until the field reflects it.
        """
        return self._send(p.read_field(world_id, box, format, min_version, self.timeout))

    def read_voxels(self, world_id: str, box: p.BoxArg = None, *, min_version: int | None = None) -> Block:
        return self._send(p.read_voxels(world_id, box, min_version, self.timeout))

    def query(self, world_id: str, points: Any, *, min_version: int | None = None) -> QueryResult:
        """Distances and gradient directions at ``points`` (N x 3, x y z)."""
        return self._send(p.query(world_id, points, min_version))

    # -- service ----------------------------------------------------------------------------------

    def ready(self) -> bool:
        """True when ``/readyz`` answers 200."""
        try:
            return self._http.get("/readyz").status_code == 200
        except httpx.TransportError:
            return False


class AsyncClient:
    """The same API as ``Client``, awaitable."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, timeout: float = DEFAULT_TIMEOUT_S,
                 transport: httpx.AsyncBaseTransport | None = None, headers: dict | None = None,
                 limits: httpx.Limits | None = None):
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        extra = {} if limits is None else {"limits": limits}
        self._http = httpx.AsyncClient(transport=transport, **_options(base_url, timeout, headers), **extra)

    async def __aenter__(self) -> "AsyncClient":
        return self

    async def __aexit__(self, *exc_info: Any) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await self._http.aclose()

    async def _send(self, call: p.Call) -> Any:
        try:
            response = await self._http.request(call.method, call.path, **call.request_kwargs())
        except httpx.TransportError as exc:
            raise _transport_error(exc, call) from exc
        return call.parse(response)

    async def create_world(self, size: Sequence[int], *, chunk_size: int = 16, max_distance: int = 255,
                           algorithm: str = "exact", focus: Any = None) -> WorldInfo:
        return await self._send(p.create_world(size, chunk_size, max_distance, algorithm, focus))

    async def list_worlds(self) -> list[WorldInfo]:
        return await self._send(p.list_worlds())

    async def get_world(self, world_id: str) -> WorldInfo:
        return await self._send(p.get_world(world_id))

    async def update_world(self, world_id: str, *, algorithm: Any = p.KEEP, focus: Any = p.KEEP,
                           max_distance: Any = p.KEEP) -> WorldInfo:
        return await self._send(p.update_world(world_id, algorithm, focus, max_distance))

    async def delete_world(self, world_id: str) -> None:
        await self._send(p.delete_world(world_id))

    async def edit(self, world_id: str, edits: Any) -> int:
        return await self._send(p.edit(world_id, edits))

    async def read_field(self, world_id: str, box: p.BoxArg = None, *, format: str = "distance",  # noqa: A002
                         min_version: int | None = None) -> Block:
        return await self._send(p.read_field(world_id, box, format, min_version, self.timeout))

    async def read_voxels(self, world_id: str, box: p.BoxArg = None, *,
                          min_version: int | None = None) -> Block:
        return await self._send(p.read_voxels(world_id, box, min_version, self.timeout))

    async def query(self, world_id: str, points: Any, *, min_version: int | None = None) -> QueryResult:
        return await self._send(p.query(world_id, points, min_version))

    async def ready(self) -> bool:
        try:
            return (await self._http.get("/readyz")).status_code == 200
        except httpx.TransportError:
            return False

    def stream(self, world_id: str, **kwargs: Any):
        """A WebSocket stream of the world (``async with client.stream(id) as s``)."""
        from sdfclient.stream import Stream

        return Stream.connect(self.base_url, world_id, **kwargs)
