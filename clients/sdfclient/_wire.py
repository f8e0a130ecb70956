"""The wire format, taken from the server's own module (``sdfserver.wire``).

One codec for both sides: msgpack with arrays as ``{dtype, shape, data}``
blobs, never nested lists, never pickle. The client trusts its server more
than the server trusts its clients, so answers may be larger (a whole
world's field) than the server accepts as a body.
"""

from __future__ import annotations

from typing import Any

from sdfserver import wire

CONTENT_TYPE = wire.CONTENT_TYPE
CONTENT_TYPES = frozenset({wire.CONTENT_TYPE, "application/x-msgpack", "application/vnd.msgpack"})
RESPONSE_LIMITS = wire.WireLimits(max_bin_len=1 << 30, max_buffer_size=1 << 30)
WireError = wire.WireError

encode = wire.encode


def decode(data: bytes) -> Any:
    """A message with every blob turned back into a NumPy array."""
    return wire.decode_arrays(wire.decode(data, RESPONSE_LIMITS))
