"""The one mapping from failures to HTTP status codes, WebSocket close codes and the error body.

Every failure answers with the same body::

    {"error": {"code": "invalid_edit", "message": "edits[0]: ...", "detail": ...}}

``code`` is the exception class's ``code`` (``sdfserver.errors``), ``detail``
is present only where there is more to say (the list of validation errors).
A 405 carries ``Allow``: every method some route serves at that path (Starlette's own 405 names
only the first route whose path matched, and ``/v1/worlds/{id}`` is three routes). ``document`` adds these answers to
the OpenAPI schema, so that it lists every status a route can return.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, Mount

from sdfserver.errors import (
    BodyTooLarge, Conflict, DeviceMemoryExceeded, Forbidden, InvalidInput, KernelBuildError, NotFound, NotReady,
    RateLimited, SdfServerError, TooLarge, TooManySubscriptions, Unauthorized,
)
from sdfserver.wire import WireError

log = logging.getLogger("sdfserver.api")

STATUS: dict[type[SdfServerError], int] = {
    InvalidInput: 422,
    NotFound: 404,
    TooLarge: 413,
    DeviceMemoryExceeded: 507,
    NotReady: 503,
    KernelBuildError: 500,
    Unauthorized: 401,
    Forbidden: 403,
    Conflict: 409,
    RateLimited: 429,
    TooManySubscriptions: 429,
}

HTTP_CODES = {401: "unauthorized", 403: "forbidden", 404: "not_found", 405: "method_not_allowed", 406: "not_acceptable",
              413: "too_large", 415: "unsupported_media_type", 422: "invalid_input"}


def status_for(exc: BaseException) -> int:
    for cls in type(exc).__mro__:
        if cls in STATUS:
            return STATUS[cls]
    return 500


def close_code_for(exc: BaseException) -> int:
    """WebSocket close code: 4000 + the HTTP status (4404 unknown world, 4503 not ready, ...)."""
    return 4000 + status_for(exc)


def error_body(code: str, message: str, detail: Any = None) -> dict[str, Any]:
    error: dict[str, Any] = {"code": code, "message": message}
    if detail is not None:
        error["detail"] = detail
    return {"error": error}


def body_for(exc: BaseException) -> tuple[int, dict[str, Any]]:
    """(status, body) for any exception: the single place failures are translated."""
    if isinstance(exc, WireError):
        return 422, error_body("invalid_input", str(exc))
    if isinstance(exc, (RequestValidationError, ValidationError)):
        detail = [{"loc": [str(p) for p in e.get("loc", ())], "msg": e.get("msg", ""), "type": e.get("type", "")}
                  for e in exc.errors()]
        first = detail[0] if detail else {"loc": [], "msg": "invalid request"}
        where = ".".join(first["loc"])
        return 422, error_body("invalid_input", f"{where}: {first['msg']}" if where else first["msg"], detail)
    if isinstance(exc, StarletteHTTPException):
        return exc.status_code, error_body(HTTP_CODES.get(exc.status_code, "http_error"), str(exc.detail))
    if isinstance(exc, SdfServerError):
        return status_for(exc), error_body(exc.code, str(exc))
    log.error("unhandled error", exc_info=exc)
    return 500, error_body("internal_error", f"{type(exc).__name__}: {exc}")


def error_response(exc: BaseException) -> Response:
    status, body = body_for(exc)
    headers = {"Retry-After": "1"} if status == 503 else None
    if isinstance(exc, RateLimited):
        headers = {"Retry-After": str(max(1, round(exc.retry_after_s)))}
    elif isinstance(exc, Unauthorized):
        headers = {"WWW-Authenticate": 'Bearer realm="sdfserver"'}
    elif isinstance(exc, BodyTooLarge):
        headers = {"Connection": "close"}
    elif isinstance(exc, StarletteHTTPException) and exc.headers:  # 405's Allow
        headers = dict(exc.headers)
    return JSONResponse(body, status_code=status, headers=headers)


ERROR_SCHEMA = {"type": "object", "required": ["error"], "properties": {"error": {
    "type": "object", "required": ["code", "message"],
    "properties": {"code": {"type": "string"}, "message": {"type": "string"}, "detail": {}}}}}
ANSWERS = {401: "No or unknown API key", 403: "Not an admin key", 404: "Unknown world (or another key's)",
           409: "The world is already on that engine",
           413: "Over a size limit", 422: "Invalid input", 429: "Over the key's request rate",
           500: "A bug, or a world whose files failed their checks (storage_error)",
           503: "Not ready, writes disabled, or min_version not reached",
           507: "The world does not fit the device memory budget"}
_READS = ("/field", "/voxels", "/export")  # answers whose size a limit bounds
_ADMIN = {("post", "/v1/worlds/{world_id}/move"), ("post", "/v1/engines/rebalance")}
_ALLOCATING = {("post", "/v1/worlds"), ("post", "/v1/worlds/import"), ("patch", "/v1/worlds/{world_id}")}


def document(schema: dict[str, Any]) -> dict[str, Any]:
    """Add the error answers each operation can give to an OpenAPI schema (in place)."""
    schema.setdefault("components", {}).setdefault("schemas", {})["Error"] = ERROR_SCHEMA
    content = {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}}
    for path, operations in schema.get("paths", {}).items():
        for method, operation in operations.items():
            if path.startswith("/v1/"):
                statuses = [401, 404, 422, 429, 500, 503]
                if method in ("post", "patch") or path.endswith(_READS):
                    statuses.append(413)
                if (method, path) in _ALLOCATING:
                    statuses.append(507)
                if (method, path) in _ADMIN:
                    statuses += [403, 409, 507]
            else:
                statuses = [503] if path == "/readyz" else []
            responses = operation.setdefault("responses", {})
            for status in statuses:
                responses[str(status)] = {"description": ANSWERS[status], "content": content}  # FastAPI's 422 too
    return schema


# The methods a 405's probe tries, in the order Allow lists them.
HTTP_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")


def allowed_methods(app: FastAPI, scope: dict[str, Any], said: str = "") -> str:
    """The ``Allow`` of a 405 at ``scope``'s path: the methods that some route of ``app`` would
    take there, with those ``said`` by the route that answered (a mounted app knows its own)."""
    allowed = {m.strip().upper() for m in said.split(",") if m.strip()}
    path, root_path = scope["path"], scope.get("root_path", "")
    for route in app.router.routes:
        if isinstance(route, Mount):  # takes every method and answers 405 itself, with its Allow
            continue
        for method in HTTP_METHODS:
            probe = {"type": "http", "method": method, "path": path, "root_path": root_path, "headers": []}
            if method not in allowed and route.matches(probe)[0] == Match.FULL:
                allowed.add(method)
    return ", ".join([m for m in HTTP_METHODS if m in allowed] + sorted(allowed.difference(HTTP_METHODS)))


def install(app: FastAPI) -> None:
    async def handle(request: Request, exc: Exception) -> JSONResponse:
        if isinstance(exc, StarletteHTTPException) and exc.status_code == 405:
            said = (exc.headers or {}).get("Allow", "")
            exc = StarletteHTTPException(405, exc.detail, {**(exc.headers or {}),
                                                            "Allow": allowed_methods(app, request.scope, said)})
        return error_response(exc)

    for cls in (SdfServerError, WireError, RequestValidationError, ValidationError, StarletteHTTPException,
                Exception):
        app.add_exception_handler(cls, handle)
