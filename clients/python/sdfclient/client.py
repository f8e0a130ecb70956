"""``Client`` and ``AsyncClient``: the HTTP API of sdfserver, in the httpx shape.

    with Client("http://127.0.0.1:8000", api_key=token) as client:
        world = client.create_world(size=(64, 64, 64))
        version = client.edit(world.id, [sphere((32, 32, 32), 6)])
        field = client.read_field(world.id, min_version=version)   # reads its own write
        png = client.render(world.id, Camera.look_at((90, 70, 90), (32, 16, 32)), format="png")
        client.export_world(world.id, "npy").array                   # the voxels, (z, y, x)

``api_key`` is sent as ``Authorization: Bearer <key>`` on every request (and on
the stream); without it the server must be an open one. Every request says
``User-Agent: sdfclient/<version>``.

A 429, or a 503 to a call that may be sent twice (not a world's creation, import
or deletion, nor an edit batch without an ``idempotency_key``), is sent again
after the server's ``Retry-After``, doubled at each further attempt, up to
``retries`` times (0: never) and as long as the wait stays within
``max_retry_wait_s``; then its error is raised, ``retry_after_s`` and all.

Both take an injectable ``transport`` (``httpx.MockTransport``,
``httpx.ASGITransport``, ...) for tests; both are context managers. The two
classes differ only in how they send a call: what is sent and how the answer
is read live in ``_protocol``.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any, Sequence

import httpx

from sdfclient import _protocol as p
from sdfclient._version import USER_AGENT
from sdfclient.errors import Timeout, TransportError
from sdfclient.models import Block, Camera, Exported, Frame, Pick, QueryResult, RayResult, SphereResult, WorldInfo

DEFAULT_TIMEOUT_S = 30.0


def _transport_error(exc: httpx.TransportError, call: p.Call) -> TransportError:
    cls = Timeout if isinstance(exc, httpx.TimeoutException) else TransportError
    return cls(f"{call.method} {call.path}: {type(exc).__name__}: {exc}")


def _options(base_url: str, timeout: float, headers: dict | None, api_key: str | None) -> dict:
    auth = {} if api_key is None else {"authorization": f"Bearer {_checked_key(api_key)}"}
    return {"base_url": base_url.rstrip("/"), "timeout": timeout,
            "headers": {"user-agent": USER_AGENT, **auth, **(headers or {})}}


def _checked_retries(retries: int, max_wait_s: float) -> tuple[int, float]:
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"retries must be an integer >= 0, got {retries!r}")
    if not max_wait_s >= 0:
        raise ValueError(f"max_retry_wait_s must be >= 0, got {max_wait_s!r}")
    return retries, float(max_wait_s)


def _checked_key(api_key: str) -> str:
    if not isinstance(api_key, str) or not api_key.strip() or any(c.isspace() for c in api_key):
        raise ValueError("api_key must be a non-empty token without spaces")
    return api_key


class Client:
    """A blocking client. Thread-safe as httpx.Client is; one per thread is simplest."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, api_key: str | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S, transport: httpx.BaseTransport | None = None,
                 headers: dict | None = None, retries: int = p.DEFAULT_RETRIES,
                 max_retry_wait_s: float = p.DEFAULT_MAX_RETRY_WAIT_S):
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self.retries, self.max_retry_wait_s = _checked_retries(retries, max_retry_wait_s)
        self._http = httpx.Client(transport=transport, **_options(base_url, timeout, headers, api_key))

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc_info: Any) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _send(self, call: p.Call) -> Any:
        kwargs = call.request_kwargs()
        for attempt in range(self.retries + 1):
            try:
                response = self._http.request(call.method, call.path, **kwargs)
            except httpx.TransportError as exc:
                raise _transport_error(exc, call) from exc
            delay = p.retry_delay(call, response, attempt, self.max_retry_wait_s) if attempt < self.retries else None
            if delay is None:
                break
            time.sleep(delay)
        return call.parse(response)

    # -- worlds ---------------------------------------------------------------------------------

    def create_world(self, size: Sequence[int], *, chunk_size: int = 16, max_distance: int = 255,
                     algorithm: str = "exact", focus: Any = None, storage: str | None = None,
                     generate: dict | None = None, **options: Any) -> WorldInfo:
        """``storage``: ``"dense"`` or ``"sparse"``; ``generate``: a sparse world's terrain
        (``{"kind": "terrain", "seed": 7, ...}``). ``options``: any of ``lod_algorithm``,
        ``borders``, ``metric``, ``signed``, ``voxel_size``, ``origin``, ``palette`` (docs/api.md).
        Left out, the server's default."""
        options = {"storage": storage, "generate": generate, **options}
        return self._send(p.create_world(size, chunk_size, max_distance, algorithm, focus, options))

    def list_worlds(self) -> list[WorldInfo]:
        return self._send(p.list_worlds())

    def get_world(self, world_id: str) -> WorldInfo:
        return self._send(p.get_world(world_id))

    def update_world(self, world_id: str, *, algorithm: Any = p.KEEP, focus: Any = p.KEEP,
                     max_distance: Any = p.KEEP, **options: Any) -> WorldInfo:
        """PATCH the named settings; ``focus=None`` removes the focus. ``options``: any of
        ``lod_algorithm``, ``borders``, ``metric``, ``signed``, ``voxel_size``, ``origin``,
        ``palette``."""
        return self._send(p.update_world(world_id, algorithm, focus, max_distance, options))

    def delete_world(self, world_id: str) -> None:
        self._send(p.delete_world(world_id))

    # -- edits and reads --------------------------------------------------------------------------

    def edit(self, world_id: str, edits: Any, *, idempotency_key: str | None = None) -> int:
        """Send one atomic batch (see ``sdfclient.edits``); returns the world's new version. With
        ``idempotency_key`` (1..128 printable ASCII characters, unique per batch) a batch sent
        again is applied once, so a 503 is retried too."""
        return self._send(p.edit(world_id, edits, idempotency_key))

    def read_field(self, world_id: str, box: p.BoxArg = None, *, format: str = "distance",  # noqa: A002
                   min_version: int | None = None) -> Block:
        """The field of ``box`` (``(min, max)``, max exclusive; None: the whole world).

        With ``min_version`` the server waits (bounded) until the field reflects it.
        """
        return self._send(p.read_field(world_id, box, format, min_version, self.timeout))

    def read_voxels(self, world_id: str, box: p.BoxArg = None, *, min_version: int | None = None) -> Block:
        return self._send(p.read_voxels(world_id, box, min_version, self.timeout))

    def query(self, world_id: str, points: Any, *, min_version: int | None = None) -> QueryResult:
        """Distances, gradients and voxel values at ``points`` (N x 3, x y z, world units)."""
        return self._send(p.query(world_id, points, min_version))

    def query_spheres(self, world_id: str, spheres: Any, *, min_version: int | None = None) -> SphereResult:
        """Clearances and ways out of collision of ``spheres`` (N x 4, x y z r, world units)."""
        return self._send(p.query_spheres(world_id, spheres, min_version))

    def query_rays(self, world_id: str, rays: Any, *, min_version: int | None = None) -> RayResult:
        """First hits of ``rays`` (N x 7, ox oy oz dx dy dz max_length, world units)."""
        return self._send(p.query_rays(world_id, rays, min_version))

    # -- files ----------------------------------------------------------------------------------

    def export_world(self, world_id: str, format: str = "snapshot", *,  # noqa: A002
                     path: str | Path | None = None) -> Exported:
        """The world as a file: ``snapshot`` (re-imports as the same world), ``npy`` (``.array``:
        uint8 (z, y, x)) or MagicaVoxel ``vox``; written to ``path`` too when given."""
        exported = self._send(p.export_world(world_id, format))
        if path is not None:
            exported.save(path)
        return exported

    def import_world(self, source: p.Source, format: str | None = None, *,  # noqa: A002
                     chunk_size: int | None = None, max_distance: int | None = None,
                     algorithm: str | None = None, model: int | None = None,
                     storage: str | None = None) -> WorldInfo:
        """A new world from a file: bytes, a path or a (z, y, x) uint8 array. The server tells
        snapshot, ``.npy`` and ``.vox`` apart by content; ``format``, if given, must agree.
        ``npy``/``vox`` take the world's settings (server defaults otherwise; the size is the
        file's, grown to whole chunks), ``storage="sparse"`` among them; a snapshot brings its
        own. ``WorldInfo.warnings`` says where a sparse world holds more device memory than the
        dense one would."""
        data, fmt = p.import_source(source, format)
        return self._send(p.import_world(data, fmt, chunk_size, max_distance, algorithm, model, storage))

    # -- frames ---------------------------------------------------------------------------------

    def render(self, world_id: str, camera: Camera | dict, *, format: str = "png",  # noqa: A002
               quality: int | None = None, **options: Any) -> Frame:
        """One frame: ``png``, ``jpeg`` (``quality`` 1..100) or raw ``rgba``. ``options``:
        ambient_occlusion, shadows, sky_rgb, light, highlight, highlight_radius, cursor."""
        return self._send(p.render(world_id, camera, format, quality, options))

    def pick(self, world_id: str, camera: Camera | dict, x: float, y: float) -> Pick | None:
        """The voxel under pixel ``(x, y)`` (a pixel's centre is +0.5), or None for sky."""
        return self._send(p.pick(world_id, camera, x, y))

    # -- service ----------------------------------------------------------------------------------

    def ready(self) -> bool:
        """True when ``/readyz`` answers 200."""
        try:
            return self._http.get("/readyz").status_code == 200
        except httpx.TransportError:
            return False


class AsyncClient:
    """The same API as ``Client``, awaitable."""

    def __init__(self, base_url: str = "http://127.0.0.1:8000", *, api_key: str | None = None,
                 timeout: float = DEFAULT_TIMEOUT_S, transport: httpx.AsyncBaseTransport | None = None,
                 headers: dict | None = None, limits: httpx.Limits | None = None,
                 retries: int = p.DEFAULT_RETRIES, max_retry_wait_s: float = p.DEFAULT_MAX_RETRY_WAIT_S):
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self.retries, self.max_retry_wait_s = _checked_retries(retries, max_retry_wait_s)
        self._api_key = api_key
        extra = {} if limits is None else {"limits": limits}
        self._http = httpx.AsyncClient(transport=transport, **_options(base_url, timeout, headers, api_key),
                                       **extra)

    async def __aenter__(self) -> "AsyncClient":
        return self

    async def __aexit__(self, *exc_info: Any) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await self._http.aclose()

    async def _send(self, call: p.Call) -> Any:
        kwargs = call.request_kwargs()
        for attempt in range(self.retries + 1):
            try:
                response = await self._http.request(call.method, call.path, **kwargs)
            except httpx.TransportError as exc:
                raise _transport_error(exc, call) from exc
            delay = p.retry_delay(call, response, attempt, self.max_retry_wait_s) if attempt < self.retries else None
            if delay is None:
                break
            await asyncio.sleep(delay)
        return call.parse(response)

    async def create_world(self, size: Sequence[int], *, chunk_size: int = 16, max_distance: int = 255,
                           algorithm: str = "exact", focus: Any = None, storage: str | None = None,
                           generate: dict | None = None, **options: Any) -> WorldInfo:
        options = {"storage": storage, "generate": generate, **options}
        return await self._send(p.create_world(size, chunk_size, max_distance, algorithm, focus, options))

    async def list_worlds(self) -> list[WorldInfo]:
        return await self._send(p.list_worlds())

    async def get_world(self, world_id: str) -> WorldInfo:
        return await self._send(p.get_world(world_id))

    async def update_world(self, world_id: str, *, algorithm: Any = p.KEEP, focus: Any = p.KEEP,
                           max_distance: Any = p.KEEP, **options: Any) -> WorldInfo:
        return await self._send(p.update_world(world_id, algorithm, focus, max_distance, options))

    async def delete_world(self, world_id: str) -> None:
        await self._send(p.delete_world(world_id))

    async def edit(self, world_id: str, edits: Any, *, idempotency_key: str | None = None) -> int:
        return await self._send(p.edit(world_id, edits, idempotency_key))

    async def read_field(self, world_id: str, box: p.BoxArg = None, *, format: str = "distance",  # noqa: A002
                         min_version: int | None = None) -> Block:
        return await self._send(p.read_field(world_id, box, format, min_version, self.timeout))

    async def read_voxels(self, world_id: str, box: p.BoxArg = None, *,
                          min_version: int | None = None) -> Block:
        return await self._send(p.read_voxels(world_id, box, min_version, self.timeout))

    async def query(self, world_id: str, points: Any, *, min_version: int | None = None) -> QueryResult:
        return await self._send(p.query(world_id, points, min_version))

    async def query_spheres(self, world_id: str, spheres: Any, *, min_version: int | None = None) -> SphereResult:
        return await self._send(p.query_spheres(world_id, spheres, min_version))

    async def query_rays(self, world_id: str, rays: Any, *, min_version: int | None = None) -> RayResult:
        return await self._send(p.query_rays(world_id, rays, min_version))

    async def export_world(self, world_id: str, format: str = "snapshot", *,  # noqa: A002
                           path: str | Path | None = None) -> Exported:
        exported = await self._send(p.export_world(world_id, format))
        if path is not None:
            await asyncio.to_thread(exported.save, path)
        return exported

    async def import_world(self, source: p.Source, format: str | None = None, *,  # noqa: A002
                           chunk_size: int | None = None, max_distance: int | None = None,
                           algorithm: str | None = None, model: int | None = None,
                           storage: str | None = None) -> WorldInfo:
        data, fmt = await asyncio.to_thread(p.import_source, source, format)
        return await self._send(p.import_world(data, fmt, chunk_size, max_distance, algorithm, model, storage))

    async def render(self, world_id: str, camera: Camera | dict, *, format: str = "png",  # noqa: A002
                     quality: int | None = None, **options: Any) -> Frame:
        return await self._send(p.render(world_id, camera, format, quality, options))

    async def pick(self, world_id: str, camera: Camera | dict, x: float, y: float) -> Pick | None:
        return await self._send(p.pick(world_id, camera, x, y))

    async def ready(self) -> bool:
        try:
            return (await self._http.get("/readyz")).status_code == 200
        except httpx.TransportError:
            return False

    def stream(self, world_id: str, **kwargs: Any):
        """A WebSocket stream of the world (``async with client.stream(id) as s``), with this client's key."""
        from sdfclient.stream import Stream

        kwargs.setdefault("api_key", self._api_key)
        return Stream.connect(self.base_url, world_id, **kwargs)
