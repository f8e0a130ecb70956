"""Request bodies in, response bodies out: JSON or msgpack, with size limits.

Requests: ``Content-Type: application/json`` (the default) or
``application/msgpack``; a body over ``max_request_bytes`` is refused with 413
before it is read in full. JSON must not contain NaN or Infinity.

Responses: ``Accept: application/msgpack`` gets msgpack with arrays as blobs;
otherwise JSON, where arrays are nested lists (small answers) — field and
voxel reads choose their own formats (see routes.py).
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from fastapi import Request
from fastapi.responses import JSONResponse, Response

from sdfserver import wire
from sdfserver.errors import InvalidInput, TooLarge

MSGPACK = wire.CONTENT_TYPE
JSON = "application/json"
OCTET = "application/octet-stream"


def _no_constant(name: str) -> Any:
    raise InvalidInput(f"JSON bodies must not contain {name}")


async def read_body(request: Request, limit: int) -> bytes:
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > limit:
        raise TooLarge(f"request body of {length} bytes exceeds the limit of {limit}")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise TooLarge(f"request body exceeds the limit of {limit} bytes")
        chunks.append(chunk)
    return b"".join(chunks)


def media_type(header: str | None) -> str:
    return (header or "").split(";")[0].strip().lower()


async def decode_body(request: Request) -> Any:
    """The request body as Python data; msgpack blobs stay maps (see wire.unpack_array)."""
    settings = request.app.state.settings
    data = await read_body(request, settings.max_request_bytes)
    kind = media_type(request.headers.get("content-type")) or JSON
    if kind == MSGPACK:
        return wire.decode(data, settings.wire_limits())
    if kind == JSON or kind.endswith("+json"):
        try:
            return json.loads(data, parse_constant=_no_constant)
        except (ValueError, RecursionError) as exc:
            raise InvalidInput(f"malformed JSON: {exc}") from None
    raise InvalidInput(f"unsupported Content-Type {kind!r}; send application/json or application/msgpack")


def wants_msgpack(request: Request) -> bool:
    accept = request.headers.get("accept", "")
    if MSGPACK in accept:
        return True
    if JSON in accept:
        return False
    return media_type(request.headers.get("content-type")) == MSGPACK


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


def respond(request: Request, content: Any, status_code: int = 200) -> Response:
    """JSON or msgpack, as the request asks; counts the bytes sent."""
    if wants_msgpack(request):
        response: Response = Response(wire.encode(content), status_code=status_code, media_type=MSGPACK)
    else:
        response = JSONResponse(_jsonable(content), status_code=status_code)
    request.app.state.metrics.bytes_out.inc(len(response.body))
    return response
