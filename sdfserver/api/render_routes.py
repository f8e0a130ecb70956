"""Frames over HTTP and the WebSocket stream, picks, and the web demo at ``/``.

- ``POST /v1/worlds/{id}/render`` with a camera (see ``sdfserver.render.parse_view``) ->
  ``image/jpeg`` (default), ``image/png`` or raw RGBA (``application/octet-stream``),
  chosen by ``?format=jpeg|png|rgba`` or the Accept header. Headers: ``X-Field-Version``
  (the field version drawn), ``X-Frame-Width``/``X-Frame-Height``, ``X-Render-Ms``.
- ``POST /v1/worlds/{id}/pick`` with a camera plus ``x``, ``y`` (pixel coordinates; a
  pixel's centre is ``+0.5``) -> ``{hit, voxel, normal, place, field_version}``.
- On ``/v1/worlds/{id}/stream``: ``{type: "camera", ...camera, max_fps?, format?, quality?}``
  sets the client's view; the server then pushes ``{type: "frame", world, version, format,
  width, height, data, render_ms, field_ms, seq, view_id, latency_ms}`` whenever the view or the
  field changed, at most ``max_fps`` a second (``view_id``: the ``id`` of the camera message
  whose view it shows; ``latency_ms``: from the rendered frame's arrival here to its message
  going to the socket). Frames are rendered by the engine between steps (one field
  version each; a ``Render`` request carries the view as plain data), encoded here, in this
  API process's thread pool, while the engine renders the next, and wait in a single slot: a
  client that reads slowly gets the newest frame, never a backlog.
- With ``format: "h264" | "vp9" | "av1"`` (and ``bitrate`` or ``crf``, ``keyframe_s``, ``encoder``,
  ``preset``: render/video.py) consecutive frames are one video stream: a ``{type: "video", codec,
  encoder, ...}`` message, then frames whose ``data`` is an encoded chunk with ``key`` and
  ``timestamp`` (microseconds), for WebCodecs. ``{type: "keyframe"}`` asks for a keyframe.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Awaitable, Callable

from fastapi import APIRouter, FastAPI, Request, WebSocketDisconnect
from fastapi.responses import FileResponse, Response
from fastapi.staticfiles import StaticFiles

from sdfserver.api.auth import access_of
from sdfserver.api.bodies import decode_body, respond
from sdfserver.api.engines import Engines
from sdfserver.api.errors import body_for
from sdfserver.engine.messages import Access
from sdfserver.errors import InvalidInput, SdfServerError
from sdfserver.incoming import short
from sdfserver.render import FORMATS, encode_frame, format_from_accept, parse_view
from sdfserver.render.encode import check_format
from sdfserver.render.video import VIDEO_FORMATS, VIDEO_KEYS, VideoRequest, VideoStream, parse_video_request, video_message

STATIC_DIR = Path(__file__).resolve().parents[1] / "web" / "static"
MAX_FPS = 240.0
DEFAULT_FPS = 30.0

router = APIRouter(prefix="/v1")
_encode_pool: ThreadPoolExecutor | None = None


def install(app: FastAPI, dependencies: list | None = None) -> None:
    """The render routes (behind ``dependencies``: the API-key guard), the static files and the demo page at ``/``."""
    app.include_router(router, dependencies=dependencies or [])
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.get("/", include_in_schema=False)
    async def index() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})


def encode_pool() -> ThreadPoolExecutor:
    global _encode_pool
    if _encode_pool is None:
        _encode_pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="sdfserver-encode")
    return _encode_pool


def _quality(raw: Any) -> int:
    if isinstance(raw, bool) or not isinstance(raw, int) or not 1 <= raw <= 100:
        raise InvalidInput(f"quality must be an integer 1..100, got {short(raw)}")
    return raw


@router.post("/worlds/{world_id}/render", summary="Render a frame (JPEG, PNG or raw RGBA)",
             response_class=Response,
             responses={200: {"content": {m: {} for m in FORMATS.values()}}})
async def render(request: Request, world_id: str, format: str | None = None) -> Response:
    body = await decode_body(request)
    camera, options = parse_view(body)
    fmt = check_format(format or (body.get("format") if isinstance(body, dict) else None)
                       or format_from_accept(request.headers.get("accept")))
    quality = _quality(body.get("quality", 85))
    engine: Engines = request.app.state.engine
    frame = await engine.render(world_id, body, None, access_of(request))
    data = await asyncio.get_running_loop().run_in_executor(
        encode_pool(), encode_frame, frame.pixels.numpy(), fmt, quality)
    request.app.state.metrics.bytes_out.inc(len(data))
    return Response(data, media_type=FORMATS[fmt], headers={
        "X-Field-Version": str(frame.field_version), "X-Frame-Width": str(camera.width),
        "X-Frame-Height": str(camera.height), "X-Render-Ms": f"{frame.device_ms:.3f}",
        "Cache-Control": "no-store"})


@router.post("/worlds/{world_id}/pick", summary="The voxel under a pixel")
async def pick(request: Request, world_id: str) -> Response:
    body = await decode_body(request)
    if not isinstance(body, dict) or "x" not in body or "y" not in body:
        raise InvalidInput("a pick needs a camera and pixel coordinates x, y")
    view = {k: v for k, v in body.items() if k not in ("x", "y")}
    camera, _ = parse_view(view)
    x, y = body["x"], body["y"]
    for name, v in (("x", x), ("y", y)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or abs(v) > 1e6:
            raise InvalidInput(f"{name} must be a finite number, got {short(v)}")
    engine: Engines = request.app.state.engine
    hit = await engine.pick(world_id, view, float(x), float(y), access_of(request))
    if hit.voxel is None:
        return respond(request, {"hit": False, "field_version": hit.field_version})
    return respond(request, {"hit": True, "voxel": list(hit.voxel), "normal": list(hit.normal),
                             "place": list(hit.place), "field_version": hit.field_version})


class FrameStream:
    """One WebSocket client's frames: render -> encode -> single slot -> send.

    Rendering and encoding are two stages that overlap: while one frame is encoded here, the
    engine renders the next, so a frame costs the longer of the two, not their sum. One
    rendered frame waits for the encoder at most (the renderer starts the next only once the
    encoder has taken it); frames are paced on a fixed schedule of ``max_fps``.

    Pictures (JPEG, PNG, RGBA) are encoded in this process's thread pool and a newer one replaces
    an unsent one in the slot. A video chunk depends on the chunks before it, so none is ever
    replaced: while the last one waits for the socket the encoder holds the newest rendered frame
    only (the renderer goes on) and encodes it once the slot is free; the frames passed over are
    the ones a slow reader loses. Video is encoded on the stream's own thread (VideoStream)."""

    def __init__(self, engine: Engines, world_id: str, send: Callable[[dict[str, Any]], Awaitable[None]],
                 access: Access | None = None):
        self.engine = engine
        self.access = access
        self.world_id = world_id
        self.send = send
        self.view: tuple | None = None  # (camera, view for the engine, format, quality or VideoRequest, max_fps)
        self.view_serial = 0
        self.view_changed = asyncio.Event()
        self.rendered: tuple | dict[str, Any] | None = None  # what waits for the encoder
        self.rendered_filled = asyncio.Event()
        self.encoder_free = asyncio.Event()
        self.encoder_free.set()
        self.encoder_wake = asyncio.Event()  # a frame was rendered, or the slot was emptied
        self.slot: list[tuple[dict[str, Any], float | None]] | None = None  # (message, loop time rendered)
        self.slot_filled = asyncio.Event()
        self.seq = 0
        self.video = VideoStream()
        self._producer: asyncio.Task | None = None
        self._tasks: list[asyncio.Task] = []

    def set_view(self, message: dict[str, Any]) -> None:
        """A ``{type: "camera", ...}`` frame; raises InvalidInput/TooLarge and keeps the old view."""
        fmt = message.get("format", "jpeg")
        if fmt in VIDEO_FORMATS:
            if message.get("quality") is not None:
                raise InvalidInput(f"quality is for pictures; {fmt} takes bitrate (bit/s) or crf")
            settings: int | VideoRequest = parse_video_request(message, fmt)
        else:
            if fmt not in FORMATS:
                raise InvalidInput(f"format must be one of {sorted(FORMATS) + list(VIDEO_FORMATS)}, got {short(fmt)}")
            given = sorted(VIDEO_KEYS & message.keys())
            if given:
                raise InvalidInput(f"{given} are settings of the video formats {list(VIDEO_FORMATS)}, not of {short(fmt)}")
            settings = _quality(message.get("quality", 80))
        view = {k: v for k, v in message.items() if k not in VIDEO_KEYS}
        camera, _ = parse_view(view)
        max_fps = message.get("max_fps", DEFAULT_FPS)
        if isinstance(max_fps, bool) or not isinstance(max_fps, (int, float)) or not 0 < max_fps <= MAX_FPS:
            raise InvalidInput(f"max_fps must be a number in (0, {MAX_FPS:g}], got {short(max_fps)}")
        self.view = (camera, view, fmt, settings, float(max_fps))
        if fmt not in VIDEO_FORMATS:
            self.video.release()  # an encoder holds frames of its own: none waits idle for video to resume
        self.view_serial += 1
        self.view_changed.set()
        if not self._tasks:
            self._tasks = [asyncio.create_task(self._encode()), asyncio.create_task(self._deliver())]
        if self._producer is None or self._producer.done():  # the first view, or resumed after an error
            self.video.restart()
            self._producer = asyncio.create_task(self._produce())

    def request_keyframe(self) -> None:
        """A ``{type: "keyframe"}`` frame: the next chunk is a keyframe, sent even if nothing changed."""
        if self.view is None or self.view[2] not in VIDEO_FORMATS:
            raise InvalidInput(f"a keyframe is asked of a video stream; send a camera with format one of "
                               f"{list(VIDEO_FORMATS)} first")
        self.video.request_keyframe()
        self.view_serial += 1  # renders the frame again even if neither view nor field changed
        self.view_changed.set()

    async def close(self) -> None:
        tasks = [t for t in (self._producer, *self._tasks) if t is not None]
        for task in tasks:
            task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, RuntimeError):
                await task  # a closed socket ends the sender with one of these
        self._producer, self._tasks = None, []
        self.video.close()

    async def _produce(self) -> None:
        loop = asyncio.get_running_loop()
        last: tuple[int, int] | None = None
        due = loop.time()
        while True:
            await self.encoder_free.wait()  # until the encoder has taken the frame before this one
            serial, view = self.view_serial, self.view
            try:
                unless = last[1] if last is not None and last[0] == serial else None
                frame = await self.engine.render(self.world_id, view[1], unless, self.access)
            except SdfServerError as exc:  # the world was deleted, the device lost: say so, stop
                self._hand_over({"type": "error", "id": None, **body_for(exc)[1]})  # after the frame before
                return
            if frame is not None:
                last = (serial, frame.field_version)
                self._hand_over((frame, view, time.monotonic()))  # not loop.time(): uvloop's counts whole ms
            # At most max_fps frames a second, on a fixed schedule (a late frame does not push the
            # later ones back); a new view wakes the loop early only after that.
            period = 1.0 / view[4]
            due = max(due + period, loop.time())
            await asyncio.sleep(due - loop.time())
            if frame is None:
                self.view_changed.clear()
                try:
                    await asyncio.wait_for(self.view_changed.wait(), timeout=period)
                except asyncio.TimeoutError:
                    pass
                due = loop.time()

    def _hand_over(self, rendered: tuple | dict[str, Any]) -> None:
        """To the encoder: a (frame, view, loop time), or an error message that follows it in order."""
        self.encoder_free.clear()
        self.rendered = rendered
        self.rendered_filled.set()
        self.encoder_wake.set()

    def _take_rendered(self) -> tuple | dict[str, Any]:
        rendered, self.rendered = self.rendered, None
        self.rendered_filled.clear()
        self.encoder_free.set()  # the engine may render the next frame while this one is encoded
        return rendered

    async def _encode(self) -> None:
        while True:
            await self.rendered_filled.wait()
            rendered = self._take_rendered()
            if isinstance(rendered, tuple) and rendered[1][2] in VIDEO_FORMATS:
                rendered = await self._newest_once_slot_empties(rendered)
            try:
                messages = await self._encoded(rendered)
            except InvalidInput as exc:  # no encoder opens for this stream: say so, stop until a new view
                if self._producer is not None:
                    self._producer.cancel()
                messages = [({"type": "error", "id": None, **body_for(exc)[1]}, None)]
            self.slot = messages
            self.slot_filled.set()

    async def _newest_once_slot_empties(self, rendered: tuple | dict[str, Any]) -> tuple | dict[str, Any]:
        """Wait until the socket has taken the last chunk, keeping only the newest rendered frame."""
        while True:
            if self.rendered is not None:
                rendered = self._take_rendered()
            if self.slot is None:
                return rendered
            self.encoder_wake.clear()
            await self.encoder_wake.wait()

    async def _encoded(self, rendered: tuple | dict[str, Any]) -> list[tuple[dict[str, Any], float | None]]:
        if isinstance(rendered, dict):
            return [(rendered, None)]
        frame, (camera, view, fmt, settings, max_fps), rendered_at = rendered
        pixels = frame.pixels.numpy()
        self.seq += 1
        message = {"type": "frame", "world": self.world_id, "version": frame.field_version, "format": fmt,
                   "width": camera.width, "height": camera.height, "render_ms": frame.device_ms,
                   "field_ms": frame.field_ms, "seq": self.seq, "view_id": view.get("id")}
        if fmt not in VIDEO_FORMATS:
            message["data"] = await asyncio.get_running_loop().run_in_executor(
                encode_pool(), encode_frame, pixels, fmt, settings)
            return [(message, rendered_at)]
        started, chunk = await self.video.encode(pixels, settings, max_fps, rendered_at)
        message.update(width=pixels.shape[1] & ~1, height=pixels.shape[0] & ~1, data=chunk.data, key=chunk.key,
                       timestamp=chunk.timestamp_us, codec=self.video.codec, encode_ms=chunk.encode_ms)
        messages = [] if started is None else [(video_message(self.world_id, started), None)]
        return messages + [(message, rendered_at)]

    async def _deliver(self) -> None:
        while True:
            await self.slot_filled.wait()
            self.slot_filled.clear()
            messages, self.slot = self.slot, None
            self.encoder_wake.set()  # a video chunk held back for this slot may be encoded now
            for message, rendered_at in messages or ():
                if rendered_at is not None:  # the render's result came in; now its encoding leaves
                    message["latency_ms"] = (time.monotonic() - rendered_at) * 1e3
                await self.send(message)


__all__ = ["FrameStream", "install", "router"]
