"""WebSocket ``/v1/worlds/{id}/stream``: edits in, changed chunks out, binary msgpack frames.

Every frame is a msgpack map with a ``type``. Client to server:

- ``{type: "edits", id?, edits: [...]}``  -> ``{type: "ack", id, version}``
- ``{type: "subscribe", id?, min, max, format?}`` (format "distance" or "packed"; the
  region is widened to whole chunks) -> ``{type: "subscribed", id, min, max, chunk_size,
  format, dtype, content, metric, signed}``, then the region's current chunks, then its changed
  chunks after every recompute. A new subscribe replaces the old one. Distances are uint8, int16
  (signed Manhattan) or float32 (Euclidean); packed chunks are uint16 whose ``content`` is
  ``distance_colour`` (Manhattan) or ``squared_distance`` (Euclidean; sdfserver/field_values.py).
  Each chunk's blob names its dtype: after a PATCH of the metric or sign, the next chunks carry
  the new one.
- ``{type: "unsubscribe", id?}`` -> ``{type: "unsubscribed", id}``
- ``{type: "ping", id?}`` -> ``{type: "pong", id}``
- ``{type: "camera", ...}`` -> ``{type: "frame", ...}`` pushes (see api/render_routes.py); with a
  video format a ``{type: "video", ...}`` message starts each video stream (docs/api.md)
- ``{type: "keyframe", id?}`` -> the next video chunk is a keyframe (a decoder that lost its place)

Server to client, besides the answers: ``{type: "chunks", world, version,
chunk_size, format, chunks: [{chunk: [cx, cy, cz], origin: [x, y, z], data:
<blob>}]}`` and ``{type: "error", id, error: {code, message}}`` for a frame that
failed (the connection stays open). An unknown world closes the socket with
4404; see errors.py for the close codes.

When the world moves to another engine the subscription is made again there (``_follow``): the
client receives the region whole again, then its changes, on the same socket.

Updates wait in single-slot mailboxes (engine/mailbox.py), in the engine process and again
in this one: a client that reads slowly gets fewer, merged frames, never a growing queue.
"""

from __future__ import annotations

import asyncio
import contextlib
from types import SimpleNamespace
from typing import Any

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from starlette.websockets import WebSocketState

from sdfserver import wire
from sdfserver.api.auth import bearer_token, client_host
from sdfserver.api.engines import Engines
from sdfserver.api.errors import body_for, close_code_for
from sdfserver.api.render_routes import FrameStream
from sdfserver.api.routes import _edits_wire, batch_record
from sdfserver.engine import Mailbox, check_subscription_region
from sdfserver.engine.messages import Access, ChunkUpdate
from sdfserver.errors import InvalidInput, SdfServerError
from sdfserver.field_values import distance_dtype, packed_content
from sdfserver.geometry import Box
from sdfserver.incoming import short

router = APIRouter(prefix="/v1")


@router.websocket("/worlds/{world_id}/stream")
async def stream(websocket: WebSocket, world_id: str) -> None:
    engine: Engines = websocket.app.state.engine
    gate = websocket.app.state.gatekeeper
    await websocket.accept()
    try:
        principal = gate.authenticate(bearer_token(websocket, allow_query=True))
        access = gate.access(principal, client_host(websocket))
        described = await engine.describe(world_id, access)
    except SdfServerError as exc:
        await websocket.close(code=close_code_for(exc), reason=str(exc)[:120])
        return
    metrics = websocket.app.state.metrics
    metrics.ws_clients.inc()
    session = StreamSession(websocket, engine, world_id, described["chunk_size"], tuple(described["size"]), access)
    try:
        await session.run()
    finally:
        metrics.ws_clients.dec()
        session.close()


# The distances of a chunk by bytes a voxel: unsigned Manhattan, signed Manhattan, Euclidean.
CHUNK_DTYPES = {1: "uint8", 2: "int16", 4: "float32"}


class StreamSession:
    def __init__(self, websocket: WebSocket, engine: Engines, world_id: str, chunk_size: int,
                 size: tuple[int, int, int], access: Access | None):
        self.websocket = websocket
        self.world_box = Box.of_size(size)
        self.engine = engine
        self.world_id = world_id
        self.chunk_size = chunk_size
        self.settings = websocket.app.state.settings
        self.access = access
        self.metrics = websocket.app.state.metrics
        self.subscription: tuple[Any, int, str, str] | None = None  # (engine, number, format, dtype)
        self.mailbox = Mailbox()
        self.wake = asyncio.Event()
        self.send_lock = asyncio.Lock()
        self.frames = FrameStream(engine, world_id, self.send, access)

    async def run(self) -> None:
        sender = asyncio.create_task(self._send_updates())
        try:
            await self._receive()
        except WebSocketDisconnect:  # gone, or aborted for not reading (connections.py) while answered
            pass
        finally:
            await self.frames.close()
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, RuntimeError):
                await sender

    def close(self) -> None:
        if self.subscription is not None:
            self.engine.unsubscribe(self.subscription[0], self.subscription[1])
            self.subscription = None
            self.mailbox = Mailbox()

    async def send(self, message: dict[str, Any]) -> None:
        data = wire.encode(message)
        async with self.send_lock:
            await self.websocket.send_bytes(data)
        self.metrics.bytes_out.inc(len(data))

    def _gone(self) -> bool:
        """Whether the connection has ended: closed, or aborted under a send (Starlette then
        refuses every later send with a RuntimeError, not WebSocketDisconnect)."""
        return WebSocketState.DISCONNECTED in (self.websocket.application_state, self.websocket.client_state)

    async def _receive(self) -> None:
        limits = self.settings.wire_limits
        while True:
            message = await self.websocket.receive()
            if message["type"] == "websocket.disconnect":
                return
            frame_id = None
            try:
                data = message.get("bytes")
                if data is None:
                    raise InvalidInput("frames must be binary msgpack")
                frame = wire.decode(data, limits)
                if not isinstance(frame, dict):
                    raise InvalidInput("a frame must be a map with a 'type'")
                frame_id = frame.get("id")
                if self.access is not None and frame.get("type") != "edits":  # edits are admitted with their batch
                    await self.engine.admit(self.access, self.world_id)
                await self._handle(frame)
            except WebSocketDisconnect:
                raise
            except Exception as exc:  # every failure answers the frame; the connection stays
                if self._gone():  # it failed sending on a connection that ended meanwhile: none to answer
                    raise WebSocketDisconnect(1006) from exc
                _, body = body_for(exc)
                await self.send({"type": "error", "id": frame_id, **body})

    async def _handle(self, frame: dict[str, Any]) -> None:
        kind, frame_id = frame.get("type"), frame.get("id")
        if kind == "edits":
            raw = _edits_wire({"edits": frame.get("edits")}, self.settings.max_ops_per_batch)
            version = await self.engine.apply_edits(self.world_id, batch_record(raw), self.access)
            await self.send({"type": "ack", "id": frame_id, "version": version})
        elif kind == "subscribe":
            await self._subscribe(frame)
        elif kind == "unsubscribe":
            self.close()
            await self.send({"type": "unsubscribed", "id": frame_id})
        elif kind == "ping":
            await self.send({"type": "pong", "id": frame_id})
        elif kind == "camera":
            self.frames.set_view(frame)
        elif kind == "keyframe":
            self.frames.request_keyframe()
        else:
            raise InvalidInput(f"unknown frame type {short(kind)}; expected edits, subscribe, unsubscribe, ping, "
                               f"camera or keyframe")

    async def _subscribe(self, frame: dict[str, Any]) -> None:
        fmt = frame.get("format", "distance")
        if fmt not in ("distance", "packed"):
            raise InvalidInput(f"format must be 'distance' or 'packed', got {short(fmt)}")
        lo, hi = (_int3(frame.get(k), k) for k in ("min", "max"))
        region = Box(lo, hi).snap(self.chunk_size)
        # Checked here too, so that a bad region is refused before "subscribed" goes out.
        check_subscription_region(region, self.world_box, self.settings.max_subscription_voxels)
        self.close()
        described = await self.engine.describe(self.world_id, self.access)
        metric, signed = described.get("metric", "manhattan"), bool(described.get("signed", False))
        config = SimpleNamespace(euclidean=metric == "euclidean", signed=signed)
        dtype = "uint16" if fmt == "packed" else distance_dtype(config).name
        content = packed_content(config) if fmt == "packed" else "distance"
        # "subscribed" goes out before the first chunks can.
        await self.send({"type": "subscribed", "id": frame.get("id"), "min": list(region.lo),
                         "max": list(region.hi), "chunk_size": self.chunk_size, "format": fmt,
                         "dtype": dtype, "content": content, "metric": metric, "signed": signed})
        self.mailbox = Mailbox(self.wake.set)
        await self._follow(region, fmt, dtype)

    async def _follow(self, region: Box, fmt: str, dtype: str) -> None:
        """Subscribe on the engine that holds the world; when it moves to another engine, again
        there (its first update is then the whole region, as after a subscribe)."""
        mailbox = self.mailbox
        moved = asyncio.Event()

        def deliver(update: ChunkUpdate) -> None:  # on this process's event loop
            mailbox.put(update.version, {tuple(key): data for key, data in update.chunks})
            if update.ended is not None and not moved.is_set():
                moved.set()
                asyncio.ensure_future(self._follow_again(subscription, region, fmt, dtype))

        engine, number = await self.engine.subscribe(self.world_id, region, fmt, self.access, deliver)
        subscription = self.subscription = (engine, number, fmt, dtype)
        self.wake.set()  # the first chunks may have come before the subscription was recorded

    async def _follow_again(self, ended: tuple[Any, int, str, str], region: Box, fmt: str, dtype: str) -> None:
        if self.subscription is not ended:  # replaced or closed meanwhile
            return
        self.engine.unsubscribe(ended[0], ended[1])
        self.subscription = None  # the sender waits for the new one (its first chunks may come first)
        try:
            await self._follow(region, fmt, dtype)
        except SdfServerError as exc:
            with contextlib.suppress(WebSocketDisconnect, RuntimeError):
                await self.send({"type": "error", "id": None, "error": body_for(exc)["error"]})

    async def _send_updates(self) -> None:
        while True:
            await self.wake.wait()
            self.wake.clear()
            subscription = self.subscription
            update = self.mailbox.take() if subscription is not None else None
            if update is None:
                continue
            cs, fmt = self.chunk_size, subscription[2]
            # Distances' dtype follows the world's metric and sign, which a PATCH may change
            # while the subscription lasts: each chunk says its own, from its size.
            chunks = [{"chunk": list(key), "origin": [c * cs for c in key],
                       "data": {"dtype": "uint16" if fmt == "packed" else CHUNK_DTYPES[len(data) // cs ** 3],
                                "shape": [cs, cs, cs], "data": data}}
                      for key, data in sorted(update.chunks.items())]
            await self.send({"type": "chunks", "world": self.world_id, "version": update.version,
                             "chunk_size": cs, "format": fmt, "chunks": chunks})
            if self.subscription is subscription:  # sent: the engine may send the next
                self.engine.taken(subscription[0], subscription[1])


def _int3(value: Any, name: str) -> tuple[int, int, int]:
    if (not isinstance(value, list) or len(value) != 3
            or any(isinstance(v, bool) or not isinstance(v, int) for v in value)):
        raise InvalidInput(f"{name} must be three integers [x, y, z], got {short(value)}")
    return tuple(value)
