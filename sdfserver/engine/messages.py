"""The typed messages between API processes and an engine process (msgspec, framed on stream sockets: ``frames.py``).

Every request is plain data the engine can log, replay and answer from any process: no
closures, never pickle. Requests are one tagged union (``type`` names the class); the engine
answers each with a ``Reply`` carrying the request's id, and pushes ``ChunkUpdate``s to
subscribers. Outputs travel in ``Outputs`` batches, one per send.

Arrays travel as ``Array`` (dtype, shape, raw bytes). An error travels as its class name in
``sdfserver.errors`` and its message, and is raised again as that class in the API process.

``Access`` is who asks (the API key's name, admin or not, the client's address): the engine
checks the world's owner and the key's rate limit in one place for every API process.
"""

from __future__ import annotations

from typing import Any, Union

import msgspec
import numpy as np

from sdfserver import errors


class Array(msgspec.Struct, array_like=True):
    dtype: str
    shape: tuple[int, ...]
    data: bytes

    @classmethod
    def of(cls, array: np.ndarray) -> "Array":
        array = np.ascontiguousarray(array)
        return cls(array.dtype.str, tuple(array.shape), array.tobytes())

    @classmethod
    def view(cls, array: np.ndarray) -> "Array":
        """As ``of``, with ``data`` a view of the array's bytes rather than a copy: for an array
        nothing writes to before the message is encoded (a query's rows and its answer)."""
        array = np.ascontiguousarray(array)
        return cls(array.dtype.str, tuple(array.shape), memoryview(array.reshape(-1).view(np.uint8)))

    def numpy(self) -> np.ndarray:
        return np.frombuffer(self.data, dtype=np.dtype(self.dtype)).reshape(self.shape)


class Access(msgspec.Struct, array_like=True):
    key: str | None  # the API key's name; None on an open server
    admin: bool
    client: str  # the client's address (the rate limit's bucket on an open server)


class Request(msgspec.Struct, tag_field="type", array_like=True):
    """A request; ``id`` is unique within the sending API process."""


class CreateWorld(Request, tag=True):
    id: int
    config: dict[str, Any]  # WorldConfig in wire form (engine.world_config_dict)
    access: Access | None = None
    voxels: Array | None = None  # an import: initial voxels, uint8 (z, y, x)
    max_owned: int = 0  # most worlds the access's key may own (0: no limit); admins have none
    owned_elsewhere: int = 0  # worlds the key owns on other engines
    snapshot: bytes | None = None  # an import of a sparse world: its snapshot file (format 2)


class DeleteWorld(Request, tag=True):
    id: int
    world_id: str
    access: Access | None = None


class Reconfigure(Request, tag=True):
    id: int
    world_id: str
    changes: dict[str, Any]  # World.reconfigure's keywords; focus as {center, size} or None
    access: Access | None = None


class Describe(Request, tag=True):
    id: int
    world_id: str | None  # None: every world the access may see
    access: Access | None = None


class ReleaseWorld(Request, tag=True):
    id: int
    world_id: str
    destination: int  # the engine (index) that takes the world
    access: Access | None = None


class AdoptWorld(Request, tag=True):
    id: int
    world_id: str
    source: int | None = None  # the engine it comes from, if that one did not hand it over
    access: Access | None = None


class ExportBricks(Request, tag=True):
    """A sparse world as a snapshot (format 2: its brick table and stored bricks); the answer is
    the file's bytes."""

    id: int
    world_id: str
    access: Access | None = None


class ApplyEdits(Request, tag=True):
    id: int
    world_id: str
    batch: bytes  # the batch as its log record (storage.codec.encode_batch); validated by the engine
    access: Access | None = None


class Read(Request, tag=True):
    id: int
    world_id: str
    kind: str  # packed, distance or voxels
    lo: tuple[int, int, int] | None = None  # None: the whole world
    hi: tuple[int, int, int] | None = None
    min_version: int = 0
    access: Access | None = None


class Query(Request, tag=True):
    id: int
    world_id: str
    rows: Array  # (N, columns) numbers in world units, as engine/query.py's KINDS[kind] says
    min_version: int = 0
    access: Access | None = None
    kind: str = "points"  # points, spheres or rays


class Render(Request, tag=True):
    id: int
    world_id: str
    view: dict[str, Any]  # a camera and options (render.parse_view)
    unless_field_version: int | None = None  # answer None when the field is still at this version
    access: Access | None = None


class Pick(Request, tag=True):
    id: int
    world_id: str
    view: dict[str, Any]
    x: float
    y: float
    access: Access | None = None


class Subscribe(Request, tag=True):
    id: int
    world_id: str
    subscription: int  # the subscriber's number within its API process
    lo: tuple[int, int, int]
    hi: tuple[int, int, int]
    format: str
    access: Access | None = None


class Unsubscribe(Request, tag=True):
    id: int
    subscription: int


class Taken(Request, tag=True):
    """The subscriber took its last update: the engine may send the next (until then its
    chunks merge in the engine's single-slot mailbox)."""

    id: int
    subscription: int


class Admit(Request, tag=True):
    """The rate limit and the world's owner alone (a WebSocket frame that needs no engine work)."""

    id: int
    access: Access
    world_id: str | None = None


class Status(Request, tag=True):
    id: int


class MetricsText(Request, tag=True):
    id: int


class CountApi(Request, tag=True):
    """What an API process counted since its last report (bytes sent, WebSocket clients)."""

    id: int
    bytes_out: int = 0
    websocket_clients: int = 0  # a change, +/-


AnyRequest = Union[CreateWorld, DeleteWorld, Reconfigure, ReleaseWorld, AdoptWorld, Describe, ExportBricks,
                   ApplyEdits, Read, Query, Render, Pick, Subscribe, Unsubscribe, Taken, Admit, Status, MetricsText,
                   CountApi]


# -- answers --------------------------------------------------------------------------------------


class ReadResult(msgspec.Struct, array_like=True):
    origin: tuple[int, int, int]  # (x, y, z) of element [0, 0, 0]
    version: int
    array: Array
    content: str = ""  # commands.ReadResult.content


class QueryResult(msgspec.Struct, array_like=True):
    version: int
    arrays: dict[str, Array]  # engine/query.py's ANSWERS[kind]


class Frame(msgspec.Struct, array_like=True):
    pixels: Array  # (height, width, 4) RGBA
    field_version: int
    device_ms: float
    field_ms: float | None


class PickResult(msgspec.Struct, array_like=True):
    field_version: int
    voxel: tuple[int, int, int] | None = None  # None: nothing hit
    normal: tuple[int, int, int] | None = None
    place: tuple[int, int, int] | None = None


class EngineStatus(msgspec.Struct, array_like=True):
    ready: bool
    reason: str | None
    device: str
    free_bytes: int  # device memory the engine may still use
    writes_disabled: str | None = None  # the log's failure, when writes are refused
    pid: int = 0  # the engine's process
    worlds: list[str] = []  # the ids of the worlds it holds
    epoch: int = 0  # how many times this engine's data directory was opened to serve
    budget_bytes: int = 0  # the device memory the engine may use in all
    busy: dict[str, Any] | None = None  # a step running past busy_step_ms: Engine.busy()


class Failure(msgspec.Struct, array_like=True):
    kind: str  # a class name in sdfserver.errors
    message: str
    retry_after_s: float | None = None


class Reply(msgspec.Struct, tag=True, array_like=True):
    id: int
    result: Any = None
    failure: Failure | None = None


class ChunkUpdate(msgspec.Struct, tag=True, array_like=True):
    subscription: int
    version: int
    chunks: list[tuple[tuple[int, int, int], bytes]]  # chunk (x, y, z) -> its bytes
    ended: str | None = None  # no update follows: the world moved to another engine


class Outputs(msgspec.Struct, array_like=True):
    items: list[Union[Reply, ChunkUpdate]]


REQUEST_ENCODER = msgspec.msgpack.Encoder()
REQUEST_DECODER = msgspec.msgpack.Decoder(AnyRequest)
OUTPUTS_DECODER = msgspec.msgpack.Decoder(Outputs)
RESULT_TYPES = {ReadResult, QueryResult, Frame, PickResult, EngineStatus}


def decode_result(raw: Any, kind: type) -> Any:
    """A reply's ``result`` (decoded as plain data) as the Struct ``kind``."""
    return msgspec.convert(raw, kind)


def failure_of(exc: BaseException) -> Failure:
    if isinstance(exc, errors.SdfServerError):
        return Failure(type(exc).__name__, exc.args[0] if exc.args else str(exc),
                       getattr(exc, "retry_after_s", None))
    return Failure("SdfServerError", f"internal error: {type(exc).__name__}: {exc}")


def raise_failure(failure: Failure) -> None:
    kind = getattr(errors, failure.kind, None)
    if not (isinstance(kind, type) and issubclass(kind, errors.SdfServerError)):
        kind = errors.SdfServerError
    if kind is errors.RateLimited:
        raise errors.RateLimited(failure.message, failure.retry_after_s or 1.0)
    exc = kind.__new__(kind)
    Exception.__init__(exc, failure.message)
    raise exc
