"""The HTTP protocol without I/O: what each call sends and how its answer is read.

``Client`` and ``AsyncClient`` differ only in how they send a ``Call``; every
request shape, every parse and the error mapping live here, once.
"""

from __future__ import annotations

import io
import os
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import httpx
import numpy as np

from sdfclient import _wire
from sdfclient._answers import (
    FRAME_TYPES, OCTET, _block, _export, _frame, _nothing, _pick, _query, _rays, _spheres, _version, _world,
    _worlds, decode,
)
from sdfclient.edits import normalize
from sdfclient.errors import ProtocolError, WritesDisabled, error_class, retry_after
from sdfclient.models import Camera, Focus

BoxArg = tuple[Sequence[int], Sequence[int]] | None
EXPORT_FORMATS = ("snapshot", "npy", "vox")
FILE_MAGICS = {"snapshot": b"SDFSNAP1", "npy": b"\x93NUMPY", "vox": b"VOX "}  # as the server tells them
RENDER_OPTIONS = ("ambient_occlusion", "shadows", "sky_rgb", "light", "highlight", "highlight_radius", "cursor")
_KEEP = object()  # update_world: leave this setting as it is


@dataclass
class Call:
    method: str
    path: str
    parse: Callable[[httpx.Response], Any]
    params: dict[str, str] = field(default_factory=dict)
    body: Any = None  # encoded with the wire module when not None
    timeout: float | None = None  # overrides the client's when the server may wait
    content: bytes | None = None  # a raw body (an uploaded file), sent as application/octet-stream
    accept: str = _wire.CONTENT_TYPE
    # Sending it twice does what sending it once does, so a 503 may be answered by sending it
    # again: false where a first attempt the server answered 503 might still have taken effect
    # (a world created, an edit batch without an Idempotency-Key applied).
    repeatable: bool = True
    headers: dict[str, str] = field(default_factory=dict)

    def request_kwargs(self) -> dict:
        headers = {"accept": self.accept, **self.headers}
        kwargs: dict[str, Any] = {"params": self.params or None, "headers": headers}
        if self.body is not None:
            headers["content-type"] = _wire.CONTENT_TYPE
            kwargs["content"] = _wire.encode(self.body)
        elif self.content is not None:
            headers["content-type"] = OCTET
            kwargs["content"] = self.content
        if self.timeout is not None:
            kwargs["timeout"] = self.timeout
        return kwargs


# -- reading answers ------------------------------------------------------------------------------


# -- retries --------------------------------------------------------------------------------------

RETRIED_STATUSES = (429, 503)
DEFAULT_RETRIES = 2
DEFAULT_MAX_RETRY_WAIT_S = 30.0
JITTER = 0.25  # each wait is stretched by up to this fraction, so that refused clients come back spread out


def retry_delay(call: Call, response: httpx.Response, attempt: int, max_wait_s: float) -> float | None:
    """Seconds to wait before sending ``call`` again after ``response`` (its ``attempt``-th
    refusal, from 0), or None when it is not sent again: only 429 and 503 answers that carry a
    ``Retry-After`` are, a 503 only for a repeatable call and never for ``writes_disabled`` (it
    lasts until the server restarts). The wait is the server's ``Retry-After``, doubled at each
    further attempt; one past ``max_wait_s`` is not waited for."""
    if response.status_code not in RETRIED_STATUSES:
        return None
    after = retry_after(response.headers.get("retry-after"))
    if after is None or (response.status_code == 503 and not call.repeatable):
        return None
    if response.status_code == 503 and error_class(503, _error_code(response)) is WritesDisabled:
        return None
    delay = after * 2 ** attempt * (1 + JITTER * random.random())
    return delay if delay <= max_wait_s else None


def _error_code(response: httpx.Response) -> str | None:
    try:
        body = decode(response)
    except ProtocolError:
        return None
    error = body.get("error") if isinstance(body, dict) else None
    return str(error.get("code")) if isinstance(error, dict) and error.get("code") else None


def _world_path(world_id: str) -> str:
    if not isinstance(world_id, str) or not world_id or "/" in world_id:
        raise ValueError(f"a world id is a non-empty string without '/', got {world_id!r}")
    return f"/v1/worlds/{world_id}"


def _box_params(box: BoxArg) -> dict[str, str]:
    if box is None:
        return {}
    lo, hi = box
    if len(lo) != 3 or len(hi) != 3:
        raise ValueError(f"a box is ((x, y, z), (x, y, z)), got {box!r}")
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    return {"min": f"{int(x0)},{int(y0)},{int(z0)}", "max": f"{int(x1)},{int(y1)},{int(z1)}"}


def _focus(focus: Any) -> dict | None:
    if focus is None or isinstance(focus, dict):
        return focus
    if isinstance(focus, Focus):
        return focus.to_wire()
    raise TypeError(f"focus must be a Focus, a dict or None, got {type(focus).__name__}")


# What a world's creation may set besides its size, chunk, cap, algorithm and focus (docs/api.md):
# left out (None), the server's default.
CREATE_OPTIONS = ("lod_algorithm", "borders", "storage", "generate", "metric", "signed", "voxel_size", "origin",
                  "palette")
# What a PATCH may change besides algorithm, focus and cap.
UPDATE_OPTIONS = ("lod_algorithm", "borders", "metric", "signed", "voxel_size", "origin", "palette")


def _option(name: str, value: Any) -> Any:
    """A creation or PATCH option in wire form (numbers as plain floats, sequences as lists)."""
    if name == "voxel_size":
        return float(value)
    if name == "origin":
        return [float(v) for v in value]
    if name == "palette":
        return [[int(c) for c in colour] for colour in value]
    return value


def create_world(size: Sequence[int], chunk_size: int, max_distance: int, algorithm: str,
                 focus: Any, options: dict[str, Any] | None = None) -> Call:
    body = {"size": [int(v) for v in size], "chunk_size": int(chunk_size),
            "max_distance": int(max_distance), "algorithm": algorithm}
    if focus is not None:
        body["focus"] = _focus(focus)
    for name, value in (options or {}).items():
        if name not in CREATE_OPTIONS:
            raise ValueError(f"create_world has no option {name!r}; the options are {', '.join(CREATE_OPTIONS)}")
        if value is not None:
            body[name] = _option(name, value)
    return Call("POST", "/v1/worlds", _world, body=body, repeatable=False)


def list_worlds() -> Call:
    return Call("GET", "/v1/worlds", _worlds)


def get_world(world_id: str) -> Call:
    return Call("GET", _world_path(world_id), _world)


def update_world(world_id: str, algorithm: Any, focus: Any, max_distance: Any,
                 options: dict[str, Any] | None = None) -> Call:
    body: dict[str, Any] = {}
    if algorithm is not _KEEP:
        body["algorithm"] = algorithm
    if focus is not _KEEP:
        body["focus"] = _focus(focus)
    if max_distance is not _KEEP:
        body["max_distance"] = int(max_distance)
    for name, value in (options or {}).items():
        if name not in UPDATE_OPTIONS:
            raise ValueError(f"update_world has no option {name!r}; the options are {', '.join(UPDATE_OPTIONS)}")
        if value is not _KEEP:
            body[name] = _option(name, value)
    if not body:
        raise ValueError("update_world needs at least one setting to change")
    return Call("PATCH", _world_path(world_id), _world, body=body)


def delete_world(world_id: str) -> Call:
    return Call("DELETE", _world_path(world_id), _nothing, repeatable=False)  # a second one: 404


MAX_IDEMPOTENCY_KEY_CHARS = 128


def edit(world_id: str, edits: Any, idempotency_key: str | None = None) -> Call:
    batch = normalize(edits)
    if not batch:
        raise ValueError("an edit batch needs at least one edit")
    headers = {}
    if idempotency_key is not None:
        if (not isinstance(idempotency_key, str) or not 0 < len(idempotency_key) <= MAX_IDEMPOTENCY_KEY_CHARS
                or not idempotency_key.isascii() or not idempotency_key.isprintable()):
            raise ValueError(f"idempotency_key must be 1..{MAX_IDEMPOTENCY_KEY_CHARS} printable ASCII characters")
        headers["idempotency-key"] = idempotency_key
    return Call("POST", _world_path(world_id) + "/edits", _version, body={"edits": batch}, headers=headers,
                repeatable=idempotency_key is not None)


def _wait_timeout(min_version: int | None, timeout: float | None) -> float | None:
    return timeout if min_version is not None else None


def read_field(world_id: str, box: BoxArg, format: str, min_version: int | None,  # noqa: A002
               timeout: float | None) -> Call:
    if format not in ("distance", "packed"):
        raise ValueError(f"format is 'distance' or 'packed', got {format!r}")
    params = {**_box_params(box), "format": format}
    if min_version is not None:
        params["min_version"] = str(int(min_version))
    return Call("GET", _world_path(world_id) + "/field", _block(format), params=params,
                timeout=_wait_timeout(min_version, timeout))


def read_voxels(world_id: str, box: BoxArg, min_version: int | None, timeout: float | None) -> Call:
    params = _box_params(box)
    if min_version is not None:
        params["min_version"] = str(int(min_version))
    return Call("GET", _world_path(world_id) + "/voxels", _block("voxels"), params=params,
                timeout=_wait_timeout(min_version, timeout))


def _rows(kind: str, rows: Any, columns: int) -> np.ndarray:
    array = np.asarray(rows, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != columns or len(array) == 0:
        raise ValueError(f"{kind} must be a non-empty N x {columns} array, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"query {kind} must be finite")
    return array.astype(np.float32)


def _query_call(world_id: str, kind: str, rows: np.ndarray, parse: Callable[[httpx.Response], Any],
                min_version: int | None) -> Call:
    params = {} if min_version is None else {"min_version": str(int(min_version))}
    return Call("POST", _world_path(world_id) + "/query", parse, params=params, body={kind: rows})


def query(world_id: str, points: Any, min_version: int | None) -> Call:
    return _query_call(world_id, "points", _rows("points", np.reshape(points, (-1, 3)), 3), _query, min_version)


def query_spheres(world_id: str, spheres: Any, min_version: int | None) -> Call:
    return _query_call(world_id, "spheres", _rows("spheres", spheres, 4), _spheres, min_version)


def query_rays(world_id: str, rays: Any, min_version: int | None) -> Call:
    return _query_call(world_id, "rays", _rows("rays", rays, 7), _rays, min_version)


def export_world(world_id: str, format: str) -> Call:  # noqa: A002
    if format not in EXPORT_FORMATS:
        raise ValueError(f"format is one of {', '.join(EXPORT_FORMATS)}, got {format!r}")
    return Call("GET", _world_path(world_id) + "/export", _export(format), params={"format": format},
                accept=OCTET)


Source = bytes | bytearray | memoryview | str | os.PathLike | np.ndarray


def import_source(source: Source, format: str | None) -> tuple[bytes, str | None]:  # noqa: A002
    """The file's bytes and the format asked for: from bytes or a path (the server tells the
    format by the file's first bytes; ``format``, if given, must agree) or a NumPy (z, y, x)
    array (sent as .npy). Reads the file: call it off an event loop."""
    if format is not None and format not in EXPORT_FORMATS:
        raise ValueError(f"format is one of {', '.join(EXPORT_FORMATS)}, got {format!r}")
    if isinstance(source, np.ndarray):
        if format not in (None, "npy"):
            raise ValueError(f"an array is uploaded as npy, not {format!r}")
        if source.ndim != 3:
            raise ValueError(f"a voxel array is 3-D (z, y, x), got shape {source.shape}")
        stream = io.BytesIO()
        np.save(stream, np.ascontiguousarray(source), allow_pickle=False)
        return stream.getvalue(), "npy"
    if isinstance(source, (bytes, bytearray, memoryview)):
        return bytes(source), format
    if isinstance(source, (str, os.PathLike)):
        return Path(source).read_bytes(), format
    raise TypeError(f"import from bytes, a path or a NumPy array, got {type(source).__name__}")


def import_world(data: bytes, format: str | None, chunk_size: int | None, max_distance: int | None,  # noqa: A002
                 algorithm: str | None, model: int | None, storage: str | None = None) -> Call:
    params = {} if format is None else {"format": format}
    kind = format or next((name for name, magic in FILE_MAGICS.items() if data.startswith(magic)), None)
    if storage not in (None, "dense", "sparse"):
        raise ValueError(f"storage is 'dense' or 'sparse', got {storage!r}")
    given = {"chunk_size": chunk_size, "max_distance": max_distance, "algorithm": algorithm, "model": model,
             "storage": storage}
    given = {k: v for k, v in given.items() if v is not None}
    if kind == "snapshot" and given:
        raise ValueError(f"a snapshot brings its own configuration; drop {', '.join(sorted(given))}")
    if "model" in given and kind != "vox":
        raise ValueError("model= picks a model of a .vox file")
    params.update({k: str(v) for k, v in given.items()})
    return Call("POST", "/v1/worlds/import", _world, params=params, content=data, repeatable=False)


def _view(camera: Camera | dict, options: dict[str, Any]) -> dict:
    if isinstance(camera, Camera):
        view = camera.to_wire()
    elif isinstance(camera, dict):
        view = dict(camera)
    else:
        raise TypeError(f"camera must be a Camera or a dict, got {type(camera).__name__}")
    view.update({k: (list(v) if isinstance(v, tuple) else v) for k, v in options.items() if v is not None})
    return view


def render(world_id: str, camera: Camera | dict, format: str, quality: int | None,  # noqa: A002
           options: dict[str, Any]) -> Call:
    if format not in FRAME_TYPES:
        raise ValueError(f"format is one of {', '.join(FRAME_TYPES)}, got {format!r}")
    unknown = sorted(set(options) - set(RENDER_OPTIONS))
    if unknown:
        raise TypeError(f"unknown render options {unknown}; known: {', '.join(RENDER_OPTIONS)}")
    view = _view(camera, options)
    if quality is not None:
        view["quality"] = int(quality)
    return Call("POST", _world_path(world_id) + "/render", _frame(format), params={"format": format},
                body=view, accept=FRAME_TYPES[format])


def pick(world_id: str, camera: Camera | dict, x: float, y: float) -> Call:
    view = _view(camera, {"x": float(x), "y": float(y)})
    return Call("POST", _world_path(world_id) + "/pick", _pick, body=view)


KEEP = _KEEP
