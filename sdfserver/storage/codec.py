"""The payload of a log record: one edit batch in its wire form, as msgpack bytes.

NumPy arrays (the ``voxels`` of a voxels edit) travel as an extension type holding
``[dtype, shape, bytes]`` — never as nested lists, never pickled.
"""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np

from sdfserver.edits import Edit, decode_brushes, parse_edits
from sdfserver.errors import CorruptData

NDARRAY_EXT = 1
_DTYPES = {"|u1", "<u2", "<u4", "<u8", "|i1", "<i2", "<i4", "<i8"}


def _default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        dtype = array.dtype.newbyteorder("<") if array.dtype.byteorder == ">" else array.dtype
        array = array.astype(dtype, copy=False)
        if dtype.str not in _DTYPES:
            raise TypeError(f"cannot log an array of dtype {array.dtype}")
        return msgpack.ExtType(NDARRAY_EXT, msgpack.packb([dtype.str, list(array.shape), array.tobytes()]))
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    raise TypeError(f"cannot log a value of type {type(value).__name__}")


def _ext_hook(code: int, data: bytes) -> Any:
    if code != NDARRAY_EXT:
        return msgpack.ExtType(code, data)
    dtype, shape, raw = msgpack.unpackb(data)
    if dtype not in _DTYPES:
        raise ValueError(f"unknown array dtype {dtype!r}")
    return np.frombuffer(raw, dtype=np.dtype(dtype)).reshape(shape)


def encode_batch(edits_wire: Any, batch_id: str | None = None) -> bytes:
    """The record payload of one batch (already-encoded bytes pass through unchanged): its edits,
    or, for a batch that carries the client's id, ``{"batch_id": id, "edits": edits}``."""
    if isinstance(edits_wire, (bytes, bytearray, memoryview)):
        return bytes(edits_wire)
    value = edits_wire if batch_id is None else {"batch_id": batch_id, "edits": edits_wire}
    return msgpack.packb(value, default=_default, use_bin_type=True)


def batch_parts(decoded: Any) -> tuple[Any, str | None]:
    """(edits, batch id or None) of a decoded record payload, in either form."""
    if isinstance(decoded, dict) and set(decoded) == {"batch_id", "edits"} and isinstance(decoded["batch_id"], str):
        return decoded["edits"], decoded["batch_id"]
    return decoded, None


def decode_batch(payload: bytes, where: str = "log record") -> Any:
    try:
        return msgpack.unpackb(payload, ext_hook=_ext_hook, raw=False, strict_map_key=False)
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise CorruptData(where, None, f"record payload is not a valid edit batch: {exc}") from None


def decode_edits(payload: bytes, where: str = "log record") -> tuple[list[Edit], str | None]:
    """A record payload's parsed edits and batch id: a batch of boxes and spheres in one msgspec
    call (``edits.decode_brushes``), any other through ``decode_batch`` and ``parse_edits``,
    which refuse what is wrong with their messages."""
    brushes = decode_brushes(payload)
    if brushes is not None:
        return brushes
    edits_wire, batch_id = batch_parts(decode_batch(payload, where))
    return parse_edits(edits_wire), batch_id
