"""The client's exception tree.

    SdfClientError
    ├── TransportError          the server could not be reached or the connection broke
    │   └── Timeout             no answer in time
    ├── ProtocolError           the server answered something the client cannot read
    ├── StreamClosed            the WebSocket stream ended (carries the close code and reason)
    └── ServerError             the server refused the request (carries status, code, message)
        ├── InvalidInput        422: bad request data; nothing was changed
        │   └── InvalidEdit     422: an edit batch that cannot be applied
        ├── Unauthorized        401: a missing or unknown API key
        ├── NotFound            404: an unknown world (or another tenant's)
        ├── TooLarge            413: a body, batch or region over a limit
        ├── RateLimited         429: the key is over its request rate (retry_after_s)
        ├── DeviceMemoryExceeded 507: the world does not fit in device memory
        ├── NotReady            503: the device cannot serve requests now
        │   ├── VersionNotReached 503: a read's min_version was not reached in time
        │   └── WritesDisabled  503: the server's write-ahead log failed; no edit is accepted
        └── InternalServerError 500 and anything else

A ``ServerError`` is chosen from the server's error ``code`` first (the names
of ``sdfserver.errors``), then from the HTTP status; ``server_error`` is the
one place that does it. Every ``ServerError`` carries ``retry_after_s`` when
the answer had a ``Retry-After`` header (429 and 503 do), else None.
"""

from __future__ import annotations

import email.utils
import time
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

    def __init__(self, message: str, *, status: int, code: str, detail: Any = None,
                 retry_after_s: float | None = None):
        self.message = message
        self.status = status
        self.code = code
        self.detail = detail
        self.retry_after_s = retry_after_s
        super().__init__(f"{status} {code}: {message}")


class InvalidInput(ServerError):
    status = 422


class InvalidEdit(InvalidInput):
    pass


class Unauthorized(ServerError):
    """A missing or unknown API key: pass ``api_key=`` to the client."""

    status = 401


class NotFound(ServerError):
    status = 404


class TooLarge(ServerError):
    status = 413


class RateLimited(ServerError):
    """The key made more requests than the server's ``rate_limit_per_s`` allows;
    ``retry_after_s`` says when the next one will be taken."""

    status = 429


class DeviceMemoryExceeded(ServerError):
    status = 507


class NotReady(ServerError):
    status = 503


class VersionNotReached(NotReady):
    pass


class WritesDisabled(NotReady):
    """The server's write-ahead log failed: it refuses every edit until it is restarted."""


class InternalServerError(ServerError):
    pass


_BY_CODE: dict[str, type[ServerError]] = {
    "invalid_input": InvalidInput,
    "invalid_edit": InvalidEdit,
    "unauthorized": Unauthorized,
    "not_found": NotFound,
    "rate_limited": RateLimited,
    "too_large": TooLarge,
    "device_memory_exceeded": DeviceMemoryExceeded,
    "not_ready": NotReady,
    "no_opencl_device": NotReady,
    "version_not_reached": VersionNotReached,
    "writes_disabled": WritesDisabled,
    "method_not_allowed": InvalidInput,
    "not_acceptable": InvalidInput,
    "unsupported_media_type": InvalidInput,
}

_BY_STATUS: dict[int, type[ServerError]] = {
    400: InvalidInput,
    401: Unauthorized,
    404: NotFound,
    405: InvalidInput,
    413: TooLarge,
    415: InvalidInput,
    422: InvalidInput,
    429: RateLimited,
    503: NotReady,
    507: DeviceMemoryExceeded,
}


def error_class(status: int, code: str | None) -> type[ServerError]:
    if code in _BY_CODE:
        return _BY_CODE[code]
    return _BY_STATUS.get(status, InternalServerError)


def retry_after(header: str | None) -> float | None:
    """Seconds from a ``Retry-After`` header (delta-seconds or an HTTP date); None if absent or unreadable."""
    if not header:
        return None
    header = header.strip()
    try:
        return max(0.0, float(header))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(header)
    except (TypeError, ValueError):
        return None
    return max(0.0, when.timestamp() - time.time())


def server_error(status: int | None, body: Any, retry_after_s: float | None = None) -> ServerError:
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
    return cls(message or f"HTTP {status}", status=status, code=code or f"http_{status}", detail=detail,
               retry_after_s=retry_after_s)


__all__ = [
    "DeviceMemoryExceeded", "InternalServerError", "InvalidEdit", "InvalidInput", "NotFound", "NotReady",
    "ProtocolError", "RateLimited", "SdfClientError", "ServerError", "StreamClosed", "Timeout", "TooLarge",
    "TransportError", "Unauthorized", "VersionNotReached", "WritesDisabled", "error_class", "retry_after",
    "server_error",
]
