"""The wire format: ``sdfclient.wire``, the server's own module (``sdfserver/wire.py``) copied
byte for byte, read with the client's limits.

One codec for both sides: msgpack with arrays as ``{dtype, shape, data}``
blobs, never nested lists, never pickle. The client trusts its server more
than the server trusts its clients, so answers may be larger (a whole
world's field) than the server accepts as a body.
"""

from __future__ import annotations

from typing import Any

from sdfclient import wire

CONTENT_TYPE = wire.CONTENT_TYPE
CONTENT_TYPES = frozenset({wire.CONTENT_TYPE, "application/x-msgpack", "application/vnd.msgpack"})
RESPONSE_LIMITS = wire.WireLimits(max_bin_len=1 << 30, max_buffer_size=1 << 30)
WireError = wire.WireError
_NESTED = (dict, list)

encode = wire.encode


def decode(data: bytes) -> Any:
    """A message with every blob turned back into a NumPy array."""
    return _arrays(wire.decode(data, RESPONSE_LIMITS))


def _arrays(value: Any) -> Any:
    # wire.decode_arrays without a call per number or string: answers are maps of mostly those, and
    # the walk cost more than the decoding. Decoded msgpack holds exact dicts and lists.
    if type(value) is dict:
        if value.keys() == wire.BLOB_KEYS:
            return wire.unpack_array(value)
        return {k: _arrays(v) if type(v) in _NESTED else v for k, v in value.items()}
    if type(value) is list:
        return [_arrays(v) if type(v) in _NESTED else v for v in value]
    return value

