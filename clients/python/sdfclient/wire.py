"""The wire protocol, shared by the server and ``clients/``: msgpack with explicit limits.

Every msgpack body and WebSocket frame is decoded with hard limits on binary,
string, array and map lengths and with extension types disabled, so a hostile
payload cannot make the decoder allocate more than the body it came in.
Nothing is ever pickled.

Arrays travel as *blobs*: a map ``{"dtype": "uint16", "shape": [n, 4], "data":
<bytes>}`` with C-ordered little-endian data. Only the dtypes in ``DTYPES`` are
accepted. ``encode`` turns NumPy arrays into blobs anywhere in a message;
``decode`` leaves blobs as maps and ``unpack_array``/``decode_arrays`` turn
them back into arrays where the receiver expects them.

This module needs only msgpack and NumPy. The Python client, a distribution of its own, carries
it as ``clients/python/sdfclient/wire.py``: the same file, byte for byte
(tests/clients/test_client_package.py), so the two sides cannot drift apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

CONTENT_TYPE = "application/msgpack"
DTYPES = ("uint8", "uint16", "uint32", "int8", "int16", "int32", "int64", "float32", "float64")
BLOB_KEYS = frozenset(("dtype", "shape", "data"))


class WireError(ValueError):
    """A message that cannot be decoded (malformed, over a limit, or a bad blob)."""


@dataclass(frozen=True)
class WireLimits:
    """Upper bounds the decoder enforces; defaults suit a 16 MiB body."""

    max_bin_len: int = 16 << 20
    max_str_len: int = 1 << 20
    max_array_len: int = 1 << 20
    max_map_len: int = 1 << 12
    max_buffer_size: int = 16 << 20
    # arrays and maps in the whole message: each costs a Python object of 56+ bytes however few
    # bytes it took on the wire, so a 16 MiB message of empty ones would grow to gigabytes
    max_containers: int = 1 << 21


DEFAULT_LIMITS = WireLimits()


def pack_array(array: np.ndarray) -> dict[str, Any]:
    """A NumPy array as a blob map (little-endian, C order)."""
    return _blob(array, copy=True)


def _blob(array: np.ndarray, copy: bool) -> dict[str, Any]:
    """``copy=False``: the data is a view of the array's bytes, for a blob packed at once."""
    array = np.asarray(array)
    dtype = array.dtype.newbyteorder("<") if array.dtype.byteorder == ">" else array.dtype
    if dtype.name not in DTYPES:
        raise WireError(f"dtype {array.dtype} cannot travel as a blob; use one of {DTYPES}")
    data = np.ascontiguousarray(array, dtype=dtype.newbyteorder("<"))
    return {"dtype": dtype.name, "shape": list(array.shape),
            "data": data.tobytes() if copy else memoryview(data.reshape(-1).view(np.uint8))}


def is_blob(value: Any) -> bool:
    return isinstance(value, dict) and value.keys() == BLOB_KEYS


def unpack_array(blob: Any, where: str = "array") -> np.ndarray:
    """A blob map back into a read-only NumPy array; WireError when it is not a valid blob."""
    if not is_blob(blob):
        raise WireError(f"{where}: expected a blob {{dtype, shape, data}}")
    dtype, shape, data = blob["dtype"], blob["shape"], blob["data"]
    if dtype not in DTYPES:
        raise WireError(f"{where}: dtype must be one of {DTYPES}, got {dtype!r}")
    if (not isinstance(shape, (list, tuple)) or len(shape) > 8
            or any(isinstance(n, bool) or not isinstance(n, int) or n < 0 for n in shape)):
        raise WireError(f"{where}: shape must be a list of non-negative integers, got {shape!r}")
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise WireError(f"{where}: data must be binary")
    dt = np.dtype(dtype).newbyteorder("<")
    count = math.prod(shape)  # Python integers: a product of huge sides must not wrap around
    if count * dt.itemsize != len(data):
        raise WireError(f"{where}: {len(data)} bytes do not hold a {dtype} array of shape {list(shape)}")
    return np.frombuffer(data, dtype=dt).reshape(shape).astype(dt.newbyteorder("="), copy=False)


def _default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return _blob(value, copy=False)  # packed before encode returns
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot encode {type(value).__name__}")


def encode(message: Any) -> bytes:
    """One message as msgpack; NumPy arrays become blobs, tuples become arrays."""
    return msgpack.packb(message, default=_default, use_bin_type=True)


def decode(data: bytes, limits: WireLimits = DEFAULT_LIMITS) -> Any:
    """One message from msgpack; WireError on malformed data, trailing bytes or an exceeded limit."""
    if len(data) > limits.max_buffer_size:
        raise WireError(f"message of {len(data)} bytes exceeds the limit of {limits.max_buffer_size}")
    left = [limits.max_containers]

    def counted(container: Any) -> Any:  # called as each array or map is finished
        left[0] -= 1
        if left[0] < 0:
            raise WireError(f"message holds more than {limits.max_containers} arrays and maps")
        return container

    try:
        return msgpack.unpackb(
            data, raw=False, strict_map_key=True, use_list=True,
            max_bin_len=limits.max_bin_len, max_str_len=limits.max_str_len,
            max_array_len=limits.max_array_len, max_map_len=limits.max_map_len,
            max_ext_len=0, ext_hook=_no_ext, list_hook=counted, object_hook=counted,
        )
    except WireError:
        raise
    except (ValueError, TypeError, msgpack.exceptions.ExtraData, msgpack.exceptions.UnpackException) as exc:
        raise WireError(f"malformed msgpack: {exc}") from None


def _no_ext(code: int, data: bytes) -> Any:
    raise WireError("msgpack extension types are not accepted")


def decode_arrays(value: Any) -> Any:
    """Replace every blob inside a decoded message by its NumPy array (a walk over maps and lists)."""
    if is_blob(value):
        return unpack_array(value)
    if isinstance(value, dict):
        return {k: decode_arrays(v) for k, v in value.items()}
    if isinstance(value, list):
        return [decode_arrays(v) for v in value]
    return value


__all__ = [
    "CONTENT_TYPE", "DEFAULT_LIMITS", "DTYPES", "WireError", "WireLimits", "decode", "decode_arrays",
    "encode", "is_blob", "pack_array", "unpack_array",
]
