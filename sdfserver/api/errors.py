"""The one mapping from failures to HTTP status codes, WebSocket close codes and the error body.

Every failure answers with the same body::

    {"error": {"code": "invalid_edit", "message": "edits[0]: ...", "detail": ...}}

``code`` is the exception class's ``code`` (``sdfserver.errors``), ``detail``
is present only where there is more to say (the list of validation errors).
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from sdfserver.errors import (
    DeviceMemoryExceeded, InvalidInput, KernelBuildError, NotFound, NotReady, RateLimited, SdfServerError,
    TooLarge, Unauthorized,
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
    RateLimited: 429,
}

HTTP_CODES = {401: "unauthorized", 404: "not_found", 405: "method_not_allowed", 406: "not_acceptable",
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


class Answered(Exception):
    """A failure already translated, in the server process, for a front to send as it is."""

    def __init__(self, status: int, body: bytes, headers: list[tuple[bytes, bytes]]):
        super().__init__(status)
        self.status, self.body, self.headers = status, body, headers

    @classmethod
    def of(cls, exc: BaseException) -> "Answered":
        response = error_response(exc)
        return cls(response.status_code, bytes(response.body), list(response.raw_headers))


def error_response(exc: BaseException) -> Response:
    if isinstance(exc, Answered):
        response = Response(exc.body, exc.status)
        response.raw_headers = list(exc.headers)
        return response
    status, body = body_for(exc)
    headers = {"Retry-After": "1"} if status == 503 else None
    if isinstance(exc, RateLimited):
        headers = {"Retry-After": str(max(1, round(exc.retry_after_s)))}
    elif isinstance(exc, Unauthorized):
        headers = {"WWW-Authenticate": 'Bearer realm="sdfserver"'}
    return JSONResponse(body, status_code=status, headers=headers)


def install(app: FastAPI) -> None:
    async def handle(request: Request, exc: Exception) -> JSONResponse:
        return error_response(exc)

    for cls in (SdfServerError, WireError, RequestValidationError, ValidationError, StarletteHTTPException,
                Exception):
        app.add_exception_handler(cls, handle)
