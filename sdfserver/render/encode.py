"""Frames to bytes: JPEG and PNG through Pillow, or raw RGBA."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from sdfserver.errors import InvalidInput
from sdfserver.incoming import short

FORMATS = {"jpeg": "image/jpeg", "png": "image/png", "rgba": "application/octet-stream"}
_BY_MEDIA_TYPE = {"image/jpeg": "jpeg", "image/jpg": "jpeg", "image/png": "png",
                  "application/octet-stream": "rgba", "image/x-rgba": "rgba"}


def format_from_accept(accept: str | None, default: str = "jpeg") -> str:
    """The first format named in an Accept header (q-values ignored), else ``default``."""
    for part in (accept or "").split(","):
        media = part.split(";")[0].strip().lower()
        if media in _BY_MEDIA_TYPE:
            return _BY_MEDIA_TYPE[media]
    return default


def check_format(name: str) -> str:
    if name not in FORMATS:
        raise InvalidInput(f"format must be one of {sorted(FORMATS)}, got {short(name)}")
    return name


def encode_frame(pixels: np.ndarray, fmt: str = "jpeg", quality: int = 85) -> bytes:
    """``pixels``: (height, width, 4) uint8 RGBA."""
    check_format(fmt)
    if fmt == "rgba":
        return np.ascontiguousarray(pixels).tobytes()
    if isinstance(quality, bool) or not isinstance(quality, int) or not 1 <= quality <= 100:
        raise InvalidInput(f"quality must be an integer 1..100, got {short(quality)}")
    buf = io.BytesIO()
    if fmt == "jpeg":
        Image.fromarray(pixels[..., :3]).save(buf, format="JPEG", quality=quality)
    else:
        Image.fromarray(pixels).save(buf, format="PNG", compress_level=1)
    return buf.getvalue()
