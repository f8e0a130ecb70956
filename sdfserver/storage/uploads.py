"""Uploaded world files: which format a file is, told by its first bytes, and how large a file
of each format holding a number of voxels can be.

An import's body is bounded in bytes (``max_import_bytes``, api/spool.py). ``upload_limit_bytes``
gives the largest file of ``max_voxels`` voxels in a format's own encoding, plus the largest
framing a valid file of that format can have, for whoever sizes a buffer for such a file:

    npy       the voxels (one byte each as exported) + a header numpy reads (at most 10,000
              bytes, numpy's own bound) + the 12-byte prefix
    snapshot  zlib's worst case for the voxels (compressBound) + the JSON header (at most
              MAX_HEADER_BYTES) + magic and length
    vox       4 bytes per solid voxel (x, y, z, colour) + chunk headers, palette and the chunks
              a MagicaVoxel file carries beside its models (materials, scene graph)
"""

from __future__ import annotations

from sdfserver.errors import InvalidInput
from sdfserver.storage.snapshot import MAX_HEADER_BYTES, SNAPSHOT_MAGIC
from sdfserver.storage.voxfile import VOX_MAGIC

NPY_MAGIC = b"\x93NUMPY"
MAGICS = {"snapshot": SNAPSHOT_MAGIC, "npy": NPY_MAGIC, "vox": VOX_MAGIC}
UPLOAD_FORMATS = tuple(MAGICS)
SNIFF_BYTES = max(len(m) for m in MAGICS.values())
NPY_FRAMING_BYTES = 12 + 10_000
SNAPSHOT_FRAMING_BYTES = len(SNAPSHOT_MAGIC) + 4 + MAX_HEADER_BYTES
VOX_FRAMING_BYTES = 1 << 16
VOX_BYTES_PER_VOXEL = 4


def detect_format(head: bytes) -> str | None:
    """The format whose magic ``head`` starts with, or None."""
    for name, magic in MAGICS.items():
        if head.startswith(magic):
            return name
    return None


def upload_format(head: bytes, given: str | None) -> str:
    """The upload's format from its first ``SNIFF_BYTES`` bytes; a ``given`` format must agree."""
    found = detect_format(head)
    if found is None:
        accepted = ", ".join(f"{name} ({magic!r})" for name, magic in MAGICS.items())
        raise InvalidInput(f"the uploaded file starts with {head[:SNIFF_BYTES]!r}, the magic of no "
                           f"format this server imports: {accepted}")
    if given is not None and given != found:
        raise InvalidInput(f"format={given} was given but the uploaded file is a {found} file "
                           f"(it starts with {MAGICS[found]!r})")
    return found


def zlib_bound(n: int) -> int:
    """zlib's compressBound: the most bytes ``zlib.compress`` makes of ``n`` bytes."""
    return n + (n >> 12) + (n >> 14) + (n >> 25) + 13


def upload_limit_bytes(format: str, max_voxels: int) -> int:  # noqa: A002
    """The largest body a ``format`` file of at most ``max_voxels`` voxels can have."""
    if format == "npy":
        return NPY_FRAMING_BYTES + max_voxels
    if format == "snapshot":
        return SNAPSHOT_FRAMING_BYTES + zlib_bound(max_voxels)
    return VOX_FRAMING_BYTES + VOX_BYTES_PER_VOXEL * max_voxels


__all__ = ["SNIFF_BYTES", "UPLOAD_FORMATS", "detect_format", "upload_format", "upload_limit_bytes"]
