"""The routes every game client or robot calls, answered without FastAPI's middleware, routing and
dependency solving: ``POST /v1/worlds/{id}/edits``, a well-formed ``GET /v1/worlds/{id}/field``
and ``POST /v1/worlds/{id}/query`` with at most ``min_version`` in its query string.

Each runs the route's own handler (``routes.post_edits``, ``routes.field_response``,
``routes.query_response``) after the
same key check (``auth.guard``), and a failure is answered by the same translation
(``errors.error_response``), so the answers are those of the full app; only the way there is
shorter. Anything else — other routes and methods, a field read whose query the full app would
have to judge (unknown, repeated or malformed parameters), an upgrade request — goes to the
FastAPI app. It is an ASGI wrapper over the public interface, so uvicorn serves it as it would
the app.
"""

from __future__ import annotations

import re
from typing import Any
from urllib.parse import unquote

from fastapi import FastAPI
from starlette.requests import ClientDisconnect, Request

from sdfserver.api import auth, routes
from sdfserver.api.errors import error_response

EDITS_PATH = re.compile(r"/v1/worlds/([^/]+)/edits")
FIELD_PATH = re.compile(r"/v1/worlds/([^/]+)/field")
QUERY_PATH = re.compile(r"/v1/worlds/([^/]+)/query")
FIELD_PARAMETERS = {"min", "max", "format", "min_version"}
FORMATS = ("distance", "packed")
MAX_VERSION_DIGITS = 18  # a version fits 63 bits; longer ones the full app judges


class HotRoutes:
    def __init__(self, app: FastAPI):
        self.app = app

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] == "http" and not _upgrading(scope):
            method, path = scope["method"], scope["path"]
            if method == "POST" and (match := EDITS_PATH.fullmatch(path)):
                return await self._answer(scope, receive, send, routes.post_edits, match[1])
            if method == "GET" and (match := FIELD_PATH.fullmatch(path)):
                query = _field_query(scope["query_string"])
                if query is not None:
                    return await self._answer(scope, receive, send, _read_field, match[1], query)
            if method == "POST" and (match := QUERY_PATH.fullmatch(path)):
                min_version = _min_version_only(scope["query_string"])
                if min_version is not None:
                    return await self._answer(scope, receive, send, routes.query_response, match[1], min_version)
        await self.app(scope, receive, send)

    async def _answer(self, scope: dict[str, Any], receive: Any, send: Any, handler: Any, *args: Any) -> None:
        scope["app"] = self.app  # what Starlette sets for request.app
        request = Request(scope, receive, send)
        try:
            await auth.guard(request)
            response = await handler(request, *args)
        except ClientDisconnect:
            return
        except Exception as exc:  # answered as the app's exception handlers answer it
            response = error_response(exc)
        await response(scope, receive, send)


def _upgrading(scope: dict[str, Any]) -> bool:
    return any(key == b"upgrade" for key, _ in scope["headers"])


def _field_query(query_string: bytes) -> dict[str, str] | None:
    """The field read's parameters when each is known, given once and well formed; None leaves
    the request to the full app, which says what is wrong."""
    pairs = query_pairs(query_string.decode("latin-1"))
    query = dict(pairs)
    if len(query) != len(pairs) or not FIELD_PARAMETERS.issuperset(query):
        return None
    if query.get("format", "distance") not in FORMATS:
        return None
    min_version = query.get("min_version", "0")
    if not (min_version.isascii() and min_version.isdigit() and len(min_version) <= MAX_VERSION_DIGITS):
        return None
    return query


def _min_version_only(query_string: bytes) -> int | None:
    """A query route's ``min_version`` (0 when there is no query string); None when the query
    string holds anything else, which the full app judges."""
    if not query_string:
        return 0
    pairs = query_pairs(query_string.decode("latin-1"))
    if len(pairs) != 1 or pairs[0][0] != "min_version":
        return None
    value = pairs[0][1]
    if not (value.isascii() and value.isdigit() and len(value) <= MAX_VERSION_DIGITS):
        return None
    return int(value)


def query_pairs(query: str) -> list[tuple[str, str]]:
    """``urllib.parse.parse_qsl(query, keep_blank_values=True)``, in a fraction of its time for
    the field read's query: a part without escapes is taken as it is, one whose only escapes are
    commas (how clients send "x,y,z") has them replaced, any other is unquoted as parse_qsl does."""
    pairs = []
    for part in query.split("&"):
        if part:
            name, _, value = part.partition("=")
            pairs.append((_unquoted(name), _unquoted(value)))
    return pairs


def _unquoted(text: str) -> str:
    if "+" in text:
        text = text.replace("+", " ")
    if "%" in text:
        commas = text.replace("%2C", ",").replace("%2c", ",")
        return commas if "%" not in commas else unquote(text)
    return text


async def _read_field(request: Request, world_id: str, query: dict[str, str]) -> Any:
    box = routes.box_param(query.get("min"), query.get("max"))
    return await routes.field_response(request, world_id, box, query.get("format", "distance"),
                                       int(query.get("min_version", "0")))
