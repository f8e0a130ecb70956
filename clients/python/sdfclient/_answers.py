"""How the server's answers are read: bodies decoded by their content type, errors raised as
the error body describes, and each call's answer parsed into the client's models. Used by
``_protocol``'s calls, which say which parser reads their answer."""

from __future__ import annotations

from typing import Any, Callable

import httpx
import numpy as np

from sdfclient import _wire
from sdfclient.errors import ProtocolError, retry_after, server_error
from sdfclient.models import Block, Exported, Frame, Pick, QueryResult, RayResult, SphereResult, WorldInfo

OCTET = "application/octet-stream"
FRAME_TYPES = {"png": "image/png", "jpeg": "image/jpeg", "rgba": OCTET}


def decode(response: httpx.Response) -> Any:
    ctype = response.headers.get("content-type", "").partition(";")[0].strip().lower()
    if not response.content:
        return None
    try:
        if ctype in _wire.CONTENT_TYPES:
            return _wire.decode(response.content)
        if ctype == "application/json" or ctype.endswith("+json"):
            return response.json()
    except ValueError as exc:
        raise ProtocolError(f"{response.request.method} {response.request.url.path}: "
                            f"unreadable {ctype} body: {exc}") from exc
    raise ProtocolError(f"{response.request.method} {response.request.url.path}: "
                        f"unexpected content type {ctype!r} (status {response.status_code})")


def checked(response: httpx.Response) -> Any:
    """The decoded body, or the ServerError the error body describes."""
    if response.status_code >= 400:
        try:
            body = decode(response)
        except ProtocolError:
            body = response.text
        raise server_error(response.status_code, body, retry_after(response.headers.get("retry-after")))
    return decode(response)


def _expect_dict(body: Any, what: str) -> dict:
    if not isinstance(body, dict):
        raise ProtocolError(f"{what}: expected an object, got {type(body).__name__}")
    return body


def _array(value: Any, dtype: Any = None, shape: Any = None) -> np.ndarray:
    """A blob decoded by the wire module, or raw bytes with dtype and shape beside them."""
    if isinstance(value, np.ndarray):
        return value
    if isinstance(value, (bytes, bytearray, memoryview)) and dtype is not None:
        array = np.frombuffer(value, dtype=np.dtype(dtype))
        return array.reshape(tuple(shape)) if shape is not None else array
    if isinstance(value, list):
        return np.asarray(value, dtype=dtype)
    raise ProtocolError(f"expected an array blob, got {type(value).__name__}")


def _block(fmt: str) -> Callable[[httpx.Response], Block]:
    def parse(response: httpx.Response) -> Block:
        body = checked(response)
        if isinstance(body, (bytes, bytearray)):  # never: decode() only returns documents
            raise ProtocolError("raw field body without headers")
        body = _expect_dict(body, "field")
        data = _array(body["data"], body.get("dtype"), body.get("shape"))
        if "shape" in body and tuple(data.shape) != tuple(body["shape"]):
            data = data.reshape(tuple(body["shape"]))
        return Block(origin=tuple(map(int, body.get("origin", (0, 0, 0)))),
                     version=int(body.get("version", 0)), data=data, format=fmt,
                     content=str(body.get("content", "")))
    return parse


def _world(response: httpx.Response) -> WorldInfo:
    return WorldInfo.from_wire(_expect_dict(checked(response), "world"))


def _worlds(response: httpx.Response) -> list[WorldInfo]:
    body = checked(response)
    if isinstance(body, dict):
        body = body.get("worlds", [])
    if not isinstance(body, list):
        raise ProtocolError(f"worlds: expected a list, got {type(body).__name__}")
    return [WorldInfo.from_wire(w) for w in body]


def _version(response: httpx.Response) -> int:
    return int(_expect_dict(checked(response), "edits")["version"])


def _nothing(response: httpx.Response) -> None:
    checked(response)


def _query(response: httpx.Response) -> QueryResult:
    body = _expect_dict(checked(response), "query")
    distances = _array(body["distances"], np.float32)
    gradients = _array(body.get("gradients", np.zeros((len(distances), 3), np.float32)), np.float32)
    colours = _array(body.get("colours", np.zeros(len(distances), np.uint8)), np.uint8)
    return QueryResult(distances=distances, gradients=gradients.reshape(-1, 3), colours=colours,
                       version=int(body.get("version", 0)))


def _spheres(response: httpx.Response) -> SphereResult:
    body = _expect_dict(checked(response), "sphere query")
    return SphereResult(clearances=_array(body["clearances"], np.float32),
                        directions=_array(body["directions"], np.float32).reshape(-1, 3),
                        version=int(body.get("version", 0)))


def _rays(response: httpx.Response) -> RayResult:
    body = _expect_dict(checked(response), "ray query")
    return RayResult(hits=_array(body["hits"]).astype(bool), distances=_array(body["distances"], np.float32),
                     normals=_array(body["normals"], np.float32).reshape(-1, 3),
                     colours=_array(body["colours"], np.uint8), voxels=_array(body["voxels"], np.int32).reshape(-1, 3),
                     version=int(body.get("version", 0)))


def _int_header(response: httpx.Response, name: str) -> int:
    try:
        return int(response.headers[name])
    except (KeyError, ValueError):
        raise ProtocolError(f"{response.request.url.path}: missing or bad {name} header") from None


def _raw(response: httpx.Response, expected: str) -> bytes:
    """A binary answer's body, or the ServerError of an error answer."""
    if response.status_code >= 400 or response.status_code == 204:
        checked(response)
        raise ProtocolError(f"{response.request.url.path}: no body (status {response.status_code})")
    ctype = response.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != expected:
        raise ProtocolError(f"{response.request.url.path}: expected {expected}, got {ctype!r}")
    return response.content


def _export(fmt: str) -> Callable[[httpx.Response], Exported]:
    def parse(response: httpx.Response) -> Exported:
        data = _raw(response, OCTET)
        disposition = response.headers.get("content-disposition", "")
        filename = disposition.partition('filename="')[2].rstrip('"') if 'filename="' in disposition else ""
        return Exported(format=fmt, version=_int_header(response, "x-sdf-version"), data=data, filename=filename)
    return parse


def _frame(fmt: str) -> Callable[[httpx.Response], Frame]:
    def parse(response: httpx.Response) -> Frame:
        data = _raw(response, FRAME_TYPES[fmt])
        render_ms = response.headers.get("x-render-ms")
        return Frame(format=fmt, data=data, field_version=_int_header(response, "x-field-version"),
                     width=_int_header(response, "x-frame-width"), height=_int_header(response, "x-frame-height"),
                     render_ms=None if render_ms is None else float(render_ms))
    return parse


def _pick(response: httpx.Response) -> Pick | None:
    body = _expect_dict(checked(response), "pick")
    if not body.get("hit"):
        return None
    return Pick(voxel=tuple(int(v) for v in body["voxel"]), normal=tuple(int(v) for v in body["normal"]),
                place=tuple(int(v) for v in body["place"]), field_version=int(body.get("field_version", 0)))


# -- building requests ------------------------------------------------------------------------------
