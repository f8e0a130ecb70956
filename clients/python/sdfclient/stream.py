"""The WebSocket stream of one world: send edits, subscribe to regions, receive changed chunks.

    async with Stream.connect("http://127.0.0.1:8000", world_id) as stream:
        await stream.subscribe(((0, 0, 0), (64, 64, 64)))         # then: all its chunks, once
        version = await stream.edit([sphere((32, 32, 32), 5)])     # waits for the ack
        async for message in stream:                               # changed chunks, acks, ...
            if message.type == "chunks" and message.version >= version: ...

With ``api_key`` the handshake carries ``Authorization: Bearer <key>`` (the
server also takes ``?access_token=`` for browsers, which cannot set headers;
a header keeps the token out of URLs and access logs). A refused key or
another tenant's world closes the stream (4401, 4404): the first ``recv``,
``edit`` or ``subscribe`` raises ``Unauthorized`` or ``NotFound``.

Frames are binary msgpack (``sdfclient.wire``) both ways. The stream is meant
for one consumer task: ``edit`` and ``subscribe`` read until their answer and
keep the messages they pass for the iterator, in order. A frame the server
refuses answers an ``error`` message, raised here as its ServerError; the
connection stays open.
"""

from __future__ import annotations

import collections
import itertools
from typing import Any, AsyncIterator, Sequence

import numpy as np
import websockets
from websockets.asyncio.client import ClientConnection, connect

from sdfclient import _wire
from sdfclient._version import USER_AGENT
from sdfclient.edits import normalize
from sdfclient.errors import ProtocolError, StreamClosed, server_error
from sdfclient.models import ChunkUpdate, StreamMessage

DEFAULT_MAX_FRAME_BYTES = 64 << 20


def stream_url(base_url: str, world_id: str) -> str:
    base = base_url.rstrip("/")
    if base.startswith("https://"):
        base = "wss://" + base[len("https://"):]
    elif base.startswith("http://"):
        base = "ws://" + base[len("http://"):]
    return f"{base}/v1/worlds/{world_id}/stream"


def _chunks(raw: Any) -> list[ChunkUpdate]:
    out = []
    for c in raw or ():
        data = c["data"]
        if not isinstance(data, np.ndarray):
            data = np.frombuffer(data, dtype=np.dtype(c["dtype"])).reshape(tuple(c["shape"]))
        out.append(ChunkUpdate(origin=tuple(int(v) for v in c["origin"]), data=data))
    return out


def closed_error(exc: websockets.ConnectionClosed) -> Exception:
    """The server closes with 4000 + an HTTP status for a refused stream (4404: unknown world)."""
    rcvd = exc.rcvd
    code, reason = (rcvd.code, rcvd.reason) if rcvd else (None, "")
    if code is not None and 4000 <= code < 5000:
        return server_error(code - 4000, {"error": {"code": "", "message": reason}})
    return StreamClosed(code, reason)


def parse_message(raw: Any) -> StreamMessage:
    if not isinstance(raw, dict) or "type" not in raw:
        raise ProtocolError(f"stream frame without a type: {raw!r:.200}")
    version = raw.get("version")
    return StreamMessage(type=str(raw["type"]), version=None if version is None else int(version),
                         chunks=_chunks(raw.get("chunks")), raw=raw)


class Stream:
    def __init__(self, ws: ClientConnection):
        self._ws = ws
        self._pending: collections.deque[StreamMessage] = collections.deque()
        self._ids = itertools.count(1)

    @classmethod
    def connect(cls, base_url: str, world_id: str, *, api_key: str | None = None, open_timeout: float = 10.0,
                max_frame_bytes: int = DEFAULT_MAX_FRAME_BYTES) -> "_Connecting":
        headers = {} if api_key is None else {"Authorization": f"Bearer {api_key}"}
        return _Connecting(cls, stream_url(base_url, world_id), open_timeout, max_frame_bytes, headers)

    async def close(self) -> None:
        await self._ws.close()

    async def __aenter__(self) -> "Stream":
        return self

    async def __aexit__(self, *exc_info: Any) -> None:
        await self.close()

    # -- sending ----------------------------------------------------------------------------------

    async def _send(self, message: dict) -> None:
        try:
            await self._ws.send(_wire.encode(message))
        except websockets.ConnectionClosed as exc:
            raise closed_error(exc) from exc

    async def subscribe(self, box: tuple[Sequence[int], Sequence[int]], *,
                        format: str = "distance") -> StreamMessage:  # noqa: A002
        """Receive the chunks of ``box`` (widened to whole chunks): first all of them, then
        the changed ones after every recompute. Replaces an earlier subscription; answers
        the server's ``subscribed`` message (``raw`` has the widened ``min``/``max``)."""
        lo, hi = ([int(v) for v in corner] for corner in box)
        return await self._request({"type": "subscribe", "min": lo, "max": hi, "format": format},
                                   "subscribed")

    async def unsubscribe(self) -> None:
        await self._request({"type": "unsubscribe"}, "unsubscribed")

    async def ping(self) -> None:
        await self._request({"type": "ping"}, "pong")

    async def set_camera(self, camera: Any, *, max_fps: float | None = None, format: str | None = None,  # noqa: A002
                         quality: int | None = None, bitrate: int | None = None, crf: int | None = None,
                         keyframe_s: float | None = None, encoder: str | None = None, preset: str | None = None,
                         **options: Any) -> None:
        """Ask for rendered frames of this view: ``frame`` messages (``raw``: data, format, width,
        height, version, render_ms, seq) follow whenever the view or the field changes, at most
        ``max_fps`` a second. ``camera`` is a ``sdfclient.Camera`` or its wire dict.

        ``format`` ``jpeg`` (``quality``), ``png`` or ``rgba`` sends pictures; ``h264``, ``vp9`` or
        ``av1`` (``bitrate`` in bit/s or ``crf``, ``keyframe_s``, ``encoder``, ``preset``) sends
        video: a ``video`` message, then one encoded chunk per ``frame``.
        ``sdfclient.video.FrameDecoder`` turns either into pictures."""
        from sdfclient._protocol import RENDER_OPTIONS, _view

        unknown = sorted(set(options) - set(RENDER_OPTIONS))
        if unknown:
            raise TypeError(f"unknown render options {unknown}; known: {', '.join(RENDER_OPTIONS)}")
        extra = {"max_fps": max_fps, "format": format, "quality": quality, "bitrate": bitrate, "crf": crf,
                 "keyframe_s": keyframe_s, "encoder": encoder, "preset": preset}
        await self._send({**_view(camera, {**options, **extra}), "type": "camera", "id": next(self._ids)})

    async def request_keyframe(self) -> None:
        """The next video frame is a keyframe (after a chunk failed to decode; ``FrameDecoder``
        says so with ``needs_keyframe``)."""
        await self._send({"type": "keyframe", "id": next(self._ids)})

    async def send_edits(self, edits: Any) -> int:
        """Send a batch without waiting; its ``ack`` message carries the returned ``id``."""
        request_id = next(self._ids)
        await self._send({"type": "edits", "id": request_id, "edits": normalize(edits)})
        return request_id

    async def edit(self, edits: Any) -> int:
        """Send a batch and wait for its acknowledgement; returns the version it became."""
        ack = await self._request({"type": "edits", "edits": normalize(edits)}, "ack")
        return int(ack.version)

    async def _request(self, message: dict, answer: str) -> StreamMessage:
        """Send a frame and read until its answer (or its error); keeps what passes for later."""
        request_id = next(self._ids)
        await self._send({**message, "id": request_id})
        held = []
        try:
            while True:
                reply = await self._receive()
                if reply.raw.get("id") == request_id and reply.type in (answer, "error"):
                    self._raise_if_error(reply)
                    return reply
                held.append(reply)
        finally:
            self._pending.extend(held)

    # -- receiving --------------------------------------------------------------------------------

    @staticmethod
    def _raise_if_error(message: StreamMessage) -> None:
        if message.type == "error":
            raw = message.raw
            raise server_error(raw.get("status"), raw.get("error", raw))

    async def _receive(self) -> StreamMessage:
        try:
            frame = await self._ws.recv()
        except websockets.ConnectionClosed as exc:
            raise closed_error(exc) from exc
        if isinstance(frame, str):
            raise ProtocolError(f"text frame on a binary stream: {frame[:200]!r}")
        return parse_message(_wire.decode(frame))

    async def recv(self) -> StreamMessage:
        """The next message; an ``error`` message raises its ServerError."""
        message = self._pending.popleft() if self._pending else await self._receive()
        self._raise_if_error(message)
        return message

    def __aiter__(self) -> AsyncIterator[StreamMessage]:
        return self._iterate()

    async def _iterate(self) -> AsyncIterator[StreamMessage]:
        while True:
            try:
                yield await self.recv()
            except StreamClosed as exc:
                if exc.code in (1000, 1001):
                    return
                raise


class _Connecting:
    """``await Stream.connect(...)`` or ``async with Stream.connect(...) as stream``."""

    def __init__(self, cls: type[Stream], url: str, open_timeout: float, max_frame_bytes: int,
                 headers: dict[str, str]):
        self._cls, self._url = cls, url
        self._open_timeout, self._max = open_timeout, max_frame_bytes
        self._headers = headers
        self._stream: Stream | None = None

    async def _open(self) -> Stream:
        try:
            ws = await connect(self._url, open_timeout=self._open_timeout, max_size=self._max,
                               compression=None, additional_headers=self._headers or None,
                               user_agent_header=USER_AGENT)
        except websockets.InvalidStatus as exc:
            status = exc.response.status_code
            body = exc.response.body or b""
            try:
                payload = _wire.decode(body) if body else None
            except ValueError:
                payload = body.decode("utf-8", "replace")
            raise server_error(status, payload) from exc
        except (OSError, TimeoutError, websockets.InvalidHandshake) as exc:
            from sdfclient.errors import TransportError

            raise TransportError(f"connect {self._url}: {type(exc).__name__}: {exc}") from exc
        return self._cls(ws)

    def __await__(self):
        return self._open().__await__()

    async def __aenter__(self) -> Stream:
        self._stream = await self._open()
        return self._stream

    async def __aexit__(self, *exc_info: Any) -> None:
        if self._stream is not None:
            await self._stream.close()
