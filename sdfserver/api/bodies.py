"""Request bodies in, response bodies out: JSON or msgpack, with size limits.

Requests: ``Content-Type: application/json`` (the default) or
``application/msgpack``; a body over ``max_request_bytes`` is refused with 413
before it is read in full. JSON must not contain NaN or Infinity.

Responses: ``Accept: application/msgpack`` (or, with no Accept naming either, a
msgpack request body) gets msgpack with arrays as blobs; otherwise JSON, where
arrays are nested lists (small answers) — field and voxel reads choose their own
formats (see routes.py). ``document_answers`` says so in the OpenAPI schema.
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
from fastapi import Request
from fastapi.responses import Response
from starlette.requests import ClientDisconnect, HTTPConnection

from sdfserver import wire
from sdfserver.errors import BodyTooLarge, InvalidInput
from sdfserver.incoming import short

MSGPACK = wire.CONTENT_TYPE
JSON = "application/json"
OCTET = "application/octet-stream"
# JSONResponse's encoding (compact, NaN refused), built once rather than per response
JSON_ENCODER = json.JSONEncoder(ensure_ascii=False, allow_nan=False, separators=(",", ":"))


class Encoded(Response):
    """An encoded body with the raw headers starlette's Response would send (any given, then
    content-length and content-type), set here instead of by Response.__init__, which costs twice
    as much: every hot request answers with one (tests/api/test_bodies.py keeps them equal)."""

    def __init__(self, body: bytes, media_type: str, status_code: int = 200,
                 headers: list[tuple[bytes, bytes]] | None = None) -> None:
        self.status_code, self.media_type, self.body, self.background = status_code, media_type, body, None
        self.raw_headers = [*(headers or ()), (b"content-length", str(len(body)).encode()),
                            (b"content-type", media_type.encode())]


def _no_constant(name: str) -> Any:
    raise InvalidInput(f"JSON bodies must not contain {name}")


def header(connection: HTTPConnection, name: bytes) -> str | None:
    """The first value of a request header (``name`` in lower case), as ``connection.headers.get``
    finds it, without building starlette's Headers: hot requests read three or four."""
    for key, value in connection.scope["headers"]:
        if key == name:
            return value.decode("latin-1")
    return None


async def read_body(request: Request, limit: int) -> bytes:
    length = header(request, b"content-length")
    if length is not None and length.isdigit() and int(length) > limit:
        raise BodyTooLarge(f"request body of {length} bytes exceeds the limit of {limit}")
    chunks, size, more = [], 0, True
    while more:  # the ASGI messages as they come: request.stream() costs twice as much
        message = await request.receive()
        if message["type"] == "http.disconnect":
            raise ClientDisconnect()
        chunk = message.get("body", b"")
        size += len(chunk)
        if size > limit:
            raise BodyTooLarge(f"request body exceeds the limit of {limit} bytes")
        chunks.append(chunk)
        more = message.get("more_body", False)
    return b"".join(chunks)


def media_type(header: str | None) -> str:
    return (header or "").split(";")[0].strip().lower()


async def decode_body(request: Request) -> Any:
    """The request body as Python data; msgpack blobs stay maps (see wire.unpack_array)."""
    settings = request.app.state.settings
    data = await read_body(request, settings.max_request_bytes)
    kind = media_type(header(request, b"content-type")) or JSON
    if kind == MSGPACK:
        return wire.decode(data, settings.wire_limits)
    if kind == JSON or kind.endswith("+json"):
        # Each '[' or '{' is at most one list or dict (fewer when inside strings): the same bound
        # as msgpack's, checked at C speed before the decoder builds anything
        containers = data.count(b"[") + data.count(b"{")
        if containers > settings.wire_limits.max_containers:
            raise InvalidInput(f"the body holds more than {settings.wire_limits.max_containers} arrays and maps")
        try:
            return json.loads(data, parse_constant=_no_constant)
        except (ValueError, RecursionError) as exc:
            raise InvalidInput(f"malformed JSON: {exc}") from None
    raise InvalidInput(f"unsupported Content-Type {short(kind)}; send application/json or application/msgpack")


def wants_msgpack(request: Request) -> bool:
    accept = header(request, b"accept") or ""
    if MSGPACK in accept:
        return True
    if JSON in accept:
        return False
    return media_type(header(request, b"content-type")) == MSGPACK


def document_answers(schema: dict[str, Any]) -> dict[str, Any]:
    """Every ``/v1`` success answer documented as JSON can come as msgpack instead (``respond``
    and the array reads negotiate it): add msgpack, with the same schema, to the OpenAPI schema
    (in place)."""
    for path, operations in schema.get("paths", {}).items():
        if not path.startswith("/v1/"):
            continue
        for operation in operations.values():
            for status, response in operation.get("responses", {}).items():
                content = response.get("content", {})
                if status.startswith("2") and JSON in content:
                    content.setdefault(MSGPACK, content[JSON])
    return schema


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def respond(request: Request, content: Any, status_code: int = 200, timed_from: float | None = None) -> Response:
    """JSON or msgpack, as the request asks; counts the bytes sent. ``timed_from``: a
    ``time.perf_counter()`` reading; the answer says in ``Server-Timing`` how long ago it was,
    its body encoded."""
    if wants_msgpack(request):
        body, kind = wire.encode(content), MSGPACK
    else:
        body, kind = JSON_ENCODER.encode(_jsonable(content)).encode(), JSON
    request.app.state.metrics.bytes_out.inc(len(body))
    headers = None if timed_from is None else [server_timing(timed_from)]
    return Encoded(body, kind, status_code, headers)


def server_timing(since: float) -> tuple[bytes, bytes]:
    """A ``Server-Timing`` header: the milliseconds since ``since`` (``time.perf_counter``)."""
    return b"server-timing", f"app;dur={(time.perf_counter() - since) * 1e3:.3f}".encode()
