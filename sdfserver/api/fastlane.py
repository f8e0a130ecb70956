"""The fast lane: the requests a game client sends many times a second, past FastAPI's router.

FastAPI spends ~200 us of CPU on each request before a handler runs (nested-router
matching, dependency solving, per-request telemetry checks) — more than the engine spends
applying a brush. The event loop shares the GIL with the engine thread, so that time caps
the whole server. The lane answers

- ``POST /v1/worlds/{id}/edits``
- ``GET  /v1/worlds/{id}/field``
- ``POST /v1/worlds/{id}/query``

itself: the same ``auth.guard``, the same handlers in ``routes.py``, the same error body
(``errors.error_response``). Everything else, and these paths with other methods, goes to
FastAPI unchanged. FastAPI keeps the three routes: OpenAPI documents them from there, and
they serve the requests when the lane is off (``create_app(..., fast_lane=False)``; the
tests compare both).

With front processes (``--fronts``, ``front.py``) the same handlers run in each front, where
``request.app.state.engine`` is the link to the server process and ``guard`` only
authenticates: the server process rate-limits and checks the owner when the command arrives.
"""

from __future__ import annotations

import re
from typing import Awaitable, Callable
from urllib.parse import parse_qsl

from starlette.requests import Request
from starlette.responses import Response
from starlette.types import ASGIApp, Receive, Scope, Send

from sdfserver.api import auth, routes
from sdfserver.api.errors import error_response
from sdfserver.errors import InvalidInput

Handler = Callable[[Request, str], Awaitable[Response]]
READ_FORMATS = ("distance", "packed")


def query_params(scope: Scope) -> dict[str, str]:
    """The query string as starlette's QueryParams reads it (a name's last value wins) at a
    fraction of its cost; the standard parser only where something is escaped."""
    text = scope["query_string"].decode("latin-1")
    if "%" in text or "+" in text:
        return dict(parse_qsl(text, keep_blank_values=True))
    params = {}
    for pair in text.split("&"):
        if pair:
            name, _, value = pair.partition("=")
            params[name] = value
    return params


def _min_version(params: dict[str, str]) -> int:
    text = params.get("min_version")
    if text is None:
        return 0
    try:
        value = int(text)
    except ValueError:
        raise InvalidInput(f"min_version must be an integer >= 0, got {text!r}") from None
    if value < 0:
        raise InvalidInput(f"min_version must be an integer >= 0, got {text!r}")
    return value


async def _field(request: Request, world_id: str) -> Response:
    params = query_params(request.scope)
    format = params.get("format", "distance")
    if format not in READ_FORMATS:
        raise InvalidInput(f"format must be 'distance' or 'packed', got {format!r}")
    box = routes.box_param(params.get("min"), params.get("max"))
    return await routes.field_response(request, world_id, box, format, _min_version(params))


async def _query(request: Request, world_id: str) -> Response:
    return await routes.query_response(request, world_id, _min_version(query_params(request.scope)))


ROUTES: dict[tuple[str, str], Handler] = {
    ("POST", "edits"): routes.post_edits,
    ("GET", "field"): _field,
    ("POST", "query"): _query,
}
PATH = re.compile(r"/v1/worlds/([^/]+)/(edits|field|query)")


def lane_route(method: str, path: str) -> tuple[Handler, str] | None:
    """(handler, world id) for a request the lane answers, else None."""
    match = PATH.fullmatch(path)
    if match is None:
        return None
    handler = ROUTES.get((method, match.group(2)))
    return None if handler is None else (handler, match.group(1))


class FastLane:
    """ASGI: the lane's requests to their handlers, the rest to ``app``."""

    def __init__(self, app: ASGIApp, state_app: ASGIApp,
                 guard: Callable[[Request], Awaitable[None]] = auth.guard):
        self.app = app
        self.state_app = state_app  # what ``request.app`` answers (the FastAPI app and its state)
        self.guard = guard

    def handler(self, scope: Scope) -> tuple[Handler, str] | None:
        if scope["type"] != "http":
            return None
        return lane_route(scope["method"], scope["path"])

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        found = self.handler(scope)
        if found is None:
            await self.app(scope, receive, send)
            return
        handler, world_id = found
        scope["app"] = self.state_app
        scope["path_params"] = {"world_id": world_id}
        request = Request(scope, receive)
        try:
            await self.guard(request)
            response = await handler(request, world_id)
        except Exception as exc:  # the one mapping to status and body, as FastAPI's handlers use
            response = error_response(exc)
        await response(scope, receive, send)
