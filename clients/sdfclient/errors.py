"""The client's exception tree.

    SdfClientError
    ├── TransportError          the server could not be reached or the connection broke
    │   └── Timeout             no answer in time
    ├── ProtocolError           the server answered something the client cannot read
    ├── StreamClosed            the WebSocket stream ended (carries the close code and reason)
    └── ServerError             the server refused the request (carries status, code, message)
        ├── InvalidInput        422: bad request data; nothing was changed
        │   └── InvalidEdit     422: an edit batch that cannot be applied
        ├── NotFound            404: an unknown world
        ├── TooLarge            413: a body, batch or region over a limit
        ├── DeviceMemoryExceeded 507: the world does not fit in device memory
        ├── NotReady            503: the device cannot serve requests now
        │   └── VersionNotReached 503: a read's min_version was not reached in time
        └── InternalServerError 500 and anything else

A ``ServerError`` is chosen from the server's error ``code`` first (the names
of ``sdfserver.errors``), then from the HTTP status; ``server_error`` is the
one place that does it.
"""

from __future__ import annotations

from typing import Any


class SdfClientError(Exception):
    """Base of every error the client raises."""


class TransportError(SdfClientError):
    pass


class Timeout(TransportError):
    pass


class ProtocolError(SdfClientError):
    pass


class StreamClosed(SdfClientError):
    def __init__(self, code: int | None, reason: str = ""):
        self.code = code
        self.reason = reason
        super().__init__(f"stream closed (code {code}): {reason}" if reason else f"stream closed (code {code})")


class ServerError(SdfClientError):
    """The server answered with an error body."""

    status: int = 500

    def __init__(self, message: str, *, status: int, code: str, detail: Any = None):
        self.message = message
        self.status = status
        self.code = code
        self.detail = detail
        super().__init__(f"{status} {code}: {message}")


class InvalidInput(ServerError):
    status = 422


class InvalidEdit(InvalidInput):
    pass


class NotFound(ServerError):
    status = 404


class TooLarge(ServerError):
    status = 413


class DeviceMemoryExceeded(ServerError):
    status = 507


class NotReady(ServerError):
    status = 503


class VersionNotReached(NotReady):
    pass


class InternalServerError(ServerError):
    pass


_BY_CODE: dict[str, type[ServerError]] = {
    "invalid_input": InvalidInput,
    "invalid_edit": InvalidEdit,
    "not_found": NotFound,
    "too_large": TooLarge,
    "device_memory_exceeded": DeviceMemoryExceeded,
    "not_ready": NotReady,
    "no_opencl_device": NotReady,
    "version_not_reached": VersionNotReached,
}

_BY_STATUS: dict[int, type[ServerError]] = {
    400: InvalidInput,
    404: NotFound,
    405: InvalidInput,
    413: TooLarge,
    415: InvalidInput,
    422: InvalidInput,
    503: NotReady,
    507: DeviceMemoryExceeded,
}


def error_class(status: int, code: str | None) -> type[ServerError]:
    if code in _BY_CODE:
        return _BY_CODE[code]
    return _BY_STATUS.get(status, InternalServerError)


def server_error(status: int | None, body: Any) -> ServerError:
    """Build the exception for an error body (``{"error": {code, message, ...}}`` or flat).

    ``status`` None (a stream's error frame) takes the status of the code's class.
    """
    error = body.get("error", body) if isinstance(body, dict) else None
    if isinstance(error, dict):
        code = str(error.get("code") or "")
        message = str(error.get("message") or error.get("detail") or "")
        detail = error.get("detail")
    else:
        code, message, detail = "", str(body if body is not None else ""), None
    cls = error_class(status or 0, code or None)
    status = cls.status if status is None else status
    return cls(message or f"HTTP {status}", status=status, code=code or f"http_{status}", detail=detail)


__all__ = [
    "DeviceMemoryExceeded", "InternalServerError", "InvalidEdit", "InvalidInput", "NotFound", "NotReady",
    "ProtocolError", "SdfClientError", "ServerError", "StreamClosed", "Timeout", "TooLarge",
    "TransportError", "VersionNotReached", "error_class", "server_error",
]
