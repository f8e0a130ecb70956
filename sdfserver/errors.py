"""The project's exception tree.

    SdfServerError
    ├── InvalidInput            bad request data; nothing was changed        (HTTP 422)
    │   ├── InvalidEdit         an edit batch that cannot be applied
    │   └── RecomputeCostExceeded  a world whose full recompute would pass the work limit
    ├── Unauthorized            a missing or unknown API key                  (HTTP 401)
    ├── Forbidden               a key that may not do this (an admin's task)  (HTTP 403)
    ├── Conflict                the request contradicts the state it finds    (HTTP 409)
    ├── NotFound                an unknown world (or another tenant's)        (HTTP 404)
    ├── TooLarge                a body, batch or region over a limit          (HTTP 413)
    ├── RateLimited             a key over its request rate                   (HTTP 429)
    ├── DeviceMemoryExceeded    a world that does not fit the memory budget   (HTTP 507)
    ├── NotReady                the device cannot serve requests now          (HTTP 503)
    │   ├── NoOpenCLDevice      no OpenCL platform or no matching device
    │   ├── VersionNotReached   a read's min_version was not reached in time
    │   ├── WritesDisabled      the write-ahead log failed; no edit is accepted
    │   ├── WorldMoved          the world moved to another engine; nothing was done
    │   └── WorldFenced         another engine took the world over; the batch was not acknowledged
    ├── KernelBuildError        an OpenCL program failed to build             (HTTP 500)
    └── StorageError            the data directory cannot be used            (HTTP 500)
        └── CorruptData         a log or snapshot fails its checks; names file and offset

The mapping to HTTP status codes lives in the API layer, in one place; the
engine raises these and knows nothing of HTTP.
"""

from __future__ import annotations


class SdfServerError(Exception):
    """Base of every error the project raises on purpose."""

    code = "internal_error"


class InvalidInput(SdfServerError):
    code = "invalid_input"


class InvalidEdit(InvalidInput):
    code = "invalid_edit"


class RecomputeCostExceeded(InvalidInput):
    """A create, import or reconfiguration whose full recompute would do more work than the
    server allows (``sdfserver/recompute_cost.py``); nothing was changed."""

    code = "recompute_cost_exceeded"


class NotFound(SdfServerError):
    code = "not_found"


class Forbidden(SdfServerError):
    code = "forbidden"


class Conflict(SdfServerError):
    code = "conflict"


class Unauthorized(SdfServerError):
    code = "unauthorized"


class RateLimited(SdfServerError):
    code = "rate_limited"

    def __init__(self, message: str, retry_after_s: float = 1.0):
        self.retry_after_s = retry_after_s
        super().__init__(message)


class TooManySubscriptions(SdfServerError):
    """The engine holds as many WebSocket subscriptions as it may, in total or for one key."""

    code = "too_many_subscriptions"


class TooLarge(SdfServerError):
    code = "too_large"


class BodyTooLarge(TooLarge):
    """A request body past its limit, refused before it was read in full: the connection is
    closed after the answer rather than the rest of the body read and dropped."""


class DeviceMemoryExceeded(SdfServerError):
    code = "device_memory_exceeded"


class NotReady(SdfServerError):
    code = "not_ready"


class NoOpenCLDevice(NotReady):
    code = "no_opencl_device"


class VersionNotReached(NotReady):
    code = "version_not_reached"


class WritesDisabled(NotReady):
    """A sync or write of the write-ahead log failed. Nothing is retried and acknowledged:
    every later write is refused with this error until the server is restarted."""

    code = "writes_disabled"


class WorldMoved(NotReady):
    """The engine asked no longer holds the world (it went to another engine); nothing of the
    request was done, so it may be asked again where the world is now (the API does so itself)."""

    code = "world_moved"


class WorldFenced(NotReady):
    """Another engine took the world over (a newer epoch) after this engine logged the batch and
    before it acknowledged it: the batch may or may not be in the world's history. Retrying it
    with its ``Idempotency-Key`` is safe; without one it may be applied twice."""

    code = "world_fenced"


class StorageError(SdfServerError):
    code = "storage_error"


class CorruptData(StorageError):
    """A log or snapshot on disk fails its checks; the message names the file and offset."""

    code = "corrupt_data"

    def __init__(self, path: str, offset: int | None, reason: str):
        self.path = str(path)
        self.offset = offset
        self.reason = reason
        where = self.path if offset is None else f"{self.path} at offset {offset}"
        super().__init__(f"corrupt data in {where}: {reason}")


class KernelBuildError(SdfServerError):
    """Carries what is needed to reproduce a failed build: file, options and the build log."""

    code = "kernel_build_error"

    def __init__(self, path: str, options: list[str], log: str):
        self.path = path
        self.options = list(options)
        self.log = log
        super().__init__(
            f"OpenCL build of {path} failed with options {' '.join(options)}:\n{log}"
        )
