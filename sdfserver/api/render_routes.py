"""Frames over HTTP and the WebSocket stream, picks, and the web demo at ``/``.

- ``POST /v1/worlds/{id}/render`` with a camera (see ``sdfserver.render.parse_view``) ->
  ``image/jpeg`` (default), ``image/png`` or raw RGBA (``application/octet-stream``),
  chosen by ``?format=jpeg|png|rgba`` or the Accept header. Headers: ``X-Field-Version``
  (the field version drawn), ``X-Frame-Width``/``X-Frame-Height``, ``X-Render-Ms``.
- ``POST /v1/worlds/{id}/pick`` with a camera plus ``x``, ``y`` (pixel coordinates; a
  pixel's centre is ``+0.5``) -> ``{hit, voxel, normal, place, field_version}``.
- On ``/v1/worlds/{id}/stream``: ``{type: "camera", ...camera, max_fps?, format?, quality?}``
  sets the client's view; the server then pushes ``{type: "frame", world, version, format,
  width, height, data, render_ms, field_ms, seq}`` whenever the view or the field changed,
  at most ``max_fps`` a second. Frames are rendered by the engine between steps (one field
  version each; a ``Render`` request carries the view as plain data), encoded here, in this
  API process's thread pool, while the engine renders the next, and wait in a single slot: a
  client that reads slowly gets the newest frame, never a backlog.
"""

from __future__ import annotations

import asyncio
import contextlib
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
from sdfserver.render import FORMATS, encode_frame, format_from_accept, parse_view
from sdfserver.render.encode import check_format

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
        raise InvalidInput(f"quality must be an integer 1..100, got {raw!r}")
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
            raise InvalidInput(f"{name} must be a finite number, got {v!r}")
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
    encoder has taken it); frames are paced on a fixed schedule of ``max_fps``."""

    def __init__(self, engine: Engines, world_id: str, send: Callable[[dict[str, Any]], Awaitable[None]],
                 access: Access | None = None):
        self.engine = engine
        self.access = access
        self.world_id = world_id
        self.send = send
        self.view: tuple | None = None  # (camera, options, format, quality, max_fps)
        self.view_serial = 0
        self.view_changed = asyncio.Event()
        self.rendered: tuple | dict[str, Any] | None = None  # what waits for the encoder
        self.rendered_filled = asyncio.Event()
        self.encoder_free = asyncio.Event()
        self.encoder_free.set()
        self.slot: dict[str, Any] | None = None
        self.slot_filled = asyncio.Event()
        self.seq = 0
        self._tasks: list[asyncio.Task] = []

    def set_view(self, message: dict[str, Any]) -> None:
        """A ``{type: "camera", ...}`` frame; raises InvalidInput/TooLarge and keeps the old view."""
        camera, options = parse_view(message)
        fmt = check_format(message.get("format", "jpeg"))
        quality = _quality(message.get("quality", 80))
        max_fps = message.get("max_fps", DEFAULT_FPS)
        if isinstance(max_fps, bool) or not isinstance(max_fps, (int, float)) or not 0 < max_fps <= MAX_FPS:
            raise InvalidInput(f"max_fps must be a number in (0, {MAX_FPS:g}], got {max_fps!r}")
        self.view = (camera, message, fmt, quality, float(max_fps))
        self.view_serial += 1
        self.view_changed.set()
        if not self._tasks:
            self._tasks = [asyncio.create_task(self._produce()), asyncio.create_task(self._encode()),
                           asyncio.create_task(self._deliver())]

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, RuntimeError):
                await task  # a closed socket ends the sender with one of these
        self._tasks = []

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
                self._tasks = [t for t in self._tasks if t is not asyncio.current_task()]
                return
            if frame is not None:
                last = (serial, frame.field_version)
                self._hand_over((frame, view))
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
        """To the encoder: a (frame, view), or an error message that follows it in order."""
        self.encoder_free.clear()
        self.rendered = rendered
        self.rendered_filled.set()

    async def _encode(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await self.rendered_filled.wait()
            self.rendered_filled.clear()
            rendered, self.rendered = self.rendered, None
            self.encoder_free.set()  # the engine may render the next frame while this one is encoded
            if isinstance(rendered, dict):
                self.slot = rendered
            else:
                frame, (camera, _, fmt, quality, _) = rendered
                data = await loop.run_in_executor(encode_pool(), encode_frame, frame.pixels.numpy(), fmt, quality)
                self.seq += 1
                self.slot = {"type": "frame", "world": self.world_id, "version": frame.field_version,
                             "format": fmt, "width": camera.width, "height": camera.height, "data": data,
                             "render_ms": frame.device_ms, "field_ms": frame.field_ms, "seq": self.seq}
            self.slot_filled.set()

    async def _deliver(self) -> None:
        while True:
            await self.slot_filled.wait()
            self.slot_filled.clear()
            message, self.slot = self.slot, None
            if message is not None:
                await self.send(message)


__all__ = ["FrameStream", "install", "router"]
