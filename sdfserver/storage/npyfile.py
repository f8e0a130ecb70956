"""``.npy`` voxel arrays: shape (z, y, x), uint8 RGB332 colours (0 = air).

Loading never unpickles (``allow_pickle=False``) and reads the header first, so a huge
declared shape is refused before any memory is allocated. Integer arrays with values in
0..255 convert to uint8; booleans become solid white (0xFF) and air.
"""

from __future__ import annotations

import io
import math
from typing import BinaryIO

import numpy as np

from sdfserver.errors import InvalidInput, TooLarge


def load_npy(data: bytes | BinaryIO, *, max_voxels: int | None = None) -> np.ndarray:
    """``data``: the file's bytes, or the file open for reading from its start (an import's
    spooled body: read once, straight into the array)."""
    stream = data if hasattr(data, "read") else io.BytesIO(data)
    start = stream.tell()
    try:
        major, _ = np.lib.format.read_magic(stream)
        read_header = (np.lib.format.read_array_header_1_0 if major == 1
                       else np.lib.format.read_array_header_2_0)
        shape, _, dtype = read_header(stream)
    except (ValueError, EOFError, SyntaxError, TypeError, OverflowError, RecursionError) as exc:
        raise InvalidInput(f"not a .npy file: {type(exc).__name__}: {str(exc)[:200]}") from None
    if len(shape) != 3 or any(n < 0 for n in shape):
        raise InvalidInput(f".npy voxels must be 3-D (z, y, x), got shape {str(shape)[:100]}")
    count = math.prod(shape)  # Python integers: huge sides must not wrap around
    if max_voxels is not None and count > max_voxels:
        raise TooLarge(f".npy array of shape {shape} has {count} voxels; the limit is {max_voxels}")
    if dtype.kind not in "biu":
        raise InvalidInput(f".npy voxels must be uint8 (or integer 0..255, or bool), got {dtype}")
    stream.seek(start)
    try:
        array = np.load(stream, allow_pickle=False)
    except (ValueError, EOFError, OSError, TypeError) as exc:
        raise InvalidInput(f"cannot read the .npy array: {str(exc)[:200]}") from None
    if array.dtype == np.bool_:
        return np.where(array, np.uint8(0xFF), np.uint8(0))
    if array.dtype != np.uint8:
        if array.size and (array.min() < 0 or array.max() > 255):
            raise InvalidInput(f".npy voxel values must be 0..255, got {array.min()}..{array.max()}")
        array = array.astype(np.uint8)
    return np.ascontiguousarray(array)


def dump_npy(voxels: np.ndarray) -> bytes:
    stream = io.BytesIO()
    np.save(stream, np.ascontiguousarray(voxels, dtype=np.uint8), allow_pickle=False)
    return stream.getvalue()


def pad_to_chunks(voxels: np.ndarray, chunk_size: int) -> np.ndarray:
    """Grow (z, y, x) up to whole chunks with air, keeping the origin."""
    padded = [-(-n // chunk_size) * chunk_size for n in voxels.shape]
    return np.pad(voxels, [(0, p - n) for p, n in zip(padded, voxels.shape)])
