"""Snapshots of a world's voxels: the on-disk file, and the download / upload format.

Layout (one format for both)::

    b"SDFSNAP1" | u32 header length | header (UTF-8 JSON) | body

A sparse world's snapshot is format 2: its body is its brick table and stored bricks
(``sparse_snapshot.py``), with ``blocks_bytes`` and ``bricks`` in the header.

The header holds ``format`` (1), ``version`` (the world version the voxels reflect),
``config`` (the world's configuration: ``size`` [sx, sy, sz], ``chunk_size``,
``max_distance``, ``algorithm``, ...), ``compression`` ("zlib"), ``dtype`` ("uint8"),
``order`` ("zyx"), ``body_bytes`` and ``body_crc32``. The body is the voxels, shape
(z, y, x), compressed with zlib. Reading checks every field and the CRC, and bounds the
decompressed size by the declared world size before inflating anything.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sdfserver.errors import CorruptData, InvalidInput, TooLarge
from sdfserver.storage.fsutil import fsync_dir, write_atomic
from sdfserver.storage.sparse_snapshot import SparseContent, check_upload, parse_sparse

SNAPSHOT_MAGIC = b"SDFSNAP1"
SNAPSHOT_PATTERN = "snap-*.sdfsnap"
_HEADER_LENGTH = struct.Struct("<I")
HEADER_AT = len(SNAPSHOT_MAGIC) + _HEADER_LENGTH.size  # the JSON header follows the magic and its length
MAX_HEADER_BYTES = 1 << 16
MAX_SIDE = 1 << 16  # a bound before any arithmetic on sizes; worlds are far smaller (world_config)
MAX_VERSION = (1 << 62) - 1  # versions are u64 in log records; far beyond any world's batches
COMPRESSION_LEVEL = 1  # voxel worlds are mostly air; level 1 is fast and already small


def snapshot_name(version: int) -> str:
    return f"snap-{version:020d}.sdfsnap"


def snapshot_version(path: Path) -> int:
    return int(path.stem.split("-", 1)[1])


@dataclass
class Snapshot:
    version: int
    config: dict[str, Any]
    voxels: np.ndarray | SparseContent  # uint8, (z, y, x); a sparse world's bricks (format 2)


def encode_snapshot(version: int, config: dict[str, Any], voxels: np.ndarray | SparseContent) -> bytes:
    if isinstance(voxels, SparseContent):
        return _encode_sparse(version, config, voxels)
    size = [int(v) for v in config["size"]]
    if voxels.dtype != np.uint8 or voxels.shape != tuple(size[::-1]):
        raise InvalidInput(f"snapshot voxels must be uint8 with shape {tuple(size[::-1])}, "
                           f"got {voxels.dtype} {voxels.shape}")
    body = zlib.compress(np.ascontiguousarray(voxels), COMPRESSION_LEVEL)
    header = json.dumps({
        "format": 1, "version": int(version), "config": config, "compression": "zlib",
        "dtype": "uint8", "order": "zyx", "body_bytes": len(body), "body_crc32": zlib.crc32(body),
    }, sort_keys=True).encode()
    return SNAPSHOT_MAGIC + _HEADER_LENGTH.pack(len(header)) + header + body


def _encode_sparse(version: int, config: dict[str, Any], content: SparseContent) -> bytes:
    blocks, bricks = content.compact()
    compressor = zlib.compressobj(COMPRESSION_LEVEL)
    body = b"".join([compressor.compress(blocks)] + [compressor.compress(part) for part in content.brick_bytes()]
                    + [compressor.flush()])
    header = json.dumps({
        "format": 2, "version": int(version), "config": config, "compression": "zlib", "dtype": "bricks",
        "order": "zyx", "blocks_bytes": len(blocks), "bricks": bricks, "brick": content.brick,
        "body_bytes": len(body), "body_crc32": zlib.crc32(body)}, sort_keys=True).encode()
    return SNAPSHOT_MAGIC + _HEADER_LENGTH.pack(len(header)) + header + body


def _read_header(view: memoryview, fail) -> tuple[Any, int]:
    """(the JSON header, the body's offset) of a snapshot; ``fail(offset, reason)`` refuses it."""
    head = HEADER_AT
    if len(view) < head or bytes(view[:8]) != SNAPSHOT_MAGIC:
        raise fail(0, "not an sdfserver snapshot (bad magic)")
    (header_len,) = _HEADER_LENGTH.unpack_from(view, 8)
    if header_len > MAX_HEADER_BYTES or head + header_len > len(view):
        raise fail(8, f"header length {header_len} is out of range")
    try:
        return json.loads(bytes(view[head:head + header_len])), head + header_len
    except (ValueError, RecursionError) as exc:  # a hostile header nests deeply
        raise fail(head, f"bad header: {type(exc).__name__}: {str(exc)[:200]}") from None


# (format, compression, dtype, order) of each format this server reads: whether it is sparse
FORMATS = {(1, "zlib", "uint8", "zyx"): False, (2, "zlib", "bricks", "zyx"): True}


def _is_sparse(header: Any, fail) -> bool:
    """Whether a snapshot header is a sparse world's (format 2) or a dense one's (format 1);
    ``fail(reason)`` refuses any other, so that no reader takes a body for what it is not."""
    fmt = tuple(header.get(k) for k in ("format", "compression", "dtype", "order")) if isinstance(header, dict) else ()
    known = (len(fmt) == 4 and type(fmt[0]) is int and all(isinstance(v, str) for v in fmt[1:])
             and fmt in FORMATS)  # an exact int: true and 1.0 equal 1 but are not a format number
    if not known:
        raise fail(f"unsupported format {str(fmt or type(header).__name__)[:200]}: this server reads "
                   f"format 1 (zlib uint8 zyx voxels) and format 2 (zlib bricks)")
    return FORMATS[fmt]


def decode_snapshot(data: bytes | memoryview, where: str = "snapshot", *,
                    max_voxels: int | None = None, corrupt=CorruptData, allow_sparse: bool = True) -> Snapshot:
    """Parse and check a snapshot. ``corrupt`` picks the error: ``CorruptData`` for files on
    disk, an ``InvalidInput`` for uploads (see ``decode_upload``)."""
    view = memoryview(data)

    def fail(offset: int | None, reason: str):
        return corrupt(where, offset, reason) if corrupt is CorruptData else corrupt(f"{where}: {reason}")

    header, body_at = _read_header(view, fail)
    head = HEADER_AT  # where the header's own defects are reported
    try:
        version, config = int(header["version"]), dict(header["config"])
        size = [int(v) for v in config["size"]]
        body_bytes, body_crc = int(header["body_bytes"]), int(header["body_crc32"])
    except (ValueError, KeyError, TypeError, OverflowError, RecursionError) as exc:  # a hostile header nests deeply
        raise fail(head, f"bad header: {type(exc).__name__}: {str(exc)[:200]}") from None
    sparse = _is_sparse(header, lambda reason: fail(head, reason))
    if not 0 <= version <= MAX_VERSION or len(size) != 3 or not 0 < min(size) <= max(size) <= MAX_SIDE:
        raise fail(head, f"bad version {version} or size {size}")
    if sparse and not allow_sparse:
        raise fail(head, "a sparse world's snapshot cannot be imported")
    if sparse:
        try:
            blocks_bytes, bricks, brick = int(header["blocks_bytes"]), int(header["bricks"]), int(header["brick"])
        except (ValueError, KeyError, TypeError) as exc:
            raise fail(head, f"bad header: {type(exc).__name__}") from None
        if brick not in (8, 16, 32, 64, 128) or any(v % brick for v in size) or not 0 <= bricks <= (
                size[0] // brick) * (size[1] // brick) * (size[2] // brick) or not 0 <= blocks_bytes <= (1 << 36):
            raise fail(head, f"bad sparse layout: brick {brick}, {bricks} bricks, {blocks_bytes} table bytes")
        raw_bytes = blocks_bytes + 3 * bricks * brick ** 3
    else:
        raw_bytes = size[0] * size[1] * size[2]
    if max_voxels is not None and not sparse and raw_bytes > max_voxels:
        raise TooLarge(f"{where}: a {size} world has {raw_bytes} voxels; the limit is {max_voxels}")
    if max_voxels is not None and sparse and max(bricks * brick ** 3, blocks_bytes) > max_voxels:
        raise TooLarge(f"{where}: {bricks} stored bricks of {brick}^3 and {blocks_bytes} table bytes; the "
                       f"limit is {max_voxels} voxels")  # before anything is inflated
    body = view[body_at:]
    if len(body) != body_bytes:
        raise fail(body_at, f"body is {len(body)} bytes, header says {body_bytes}")
    if zlib.crc32(body) != body_crc:
        raise fail(body_at, "body CRC mismatch")
    inflater = zlib.decompressobj()
    try:
        raw = inflater.decompress(body, raw_bytes + 1)
    except zlib.error as exc:
        raise fail(body_at, f"cannot decompress body: {exc}") from None
    if len(raw) != raw_bytes or inflater.unconsumed_tail or not inflater.eof:
        raise fail(body_at, f"body inflates to a size other than the declared {raw_bytes} bytes")
    if sparse:
        return Snapshot(version, config, parse_sparse(raw, blocks_bytes, bricks, brick, fail))
    voxels = np.frombuffer(raw, dtype=np.uint8).reshape(size[::-1]).copy()
    return Snapshot(version, config, voxels)


def decode_upload(data: bytes, max_voxels: int | None = None) -> Snapshot:
    """A snapshot sent by a client: any defect is the client's (422 / 413). Imports make dense
    worlds, so a sparse world's snapshot is refused (422)."""
    return decode_snapshot(data, "uploaded snapshot", max_voxels=max_voxels, corrupt=InvalidInput,
                           allow_sparse=False)


def snapshot_version_of(data: bytes | memoryview) -> int:
    """The world version a snapshot file holds, from its header alone (a file this server made:
    an export's ``X-Sdf-Version``)."""
    header, _ = _read_header(memoryview(data), lambda at, reason: CorruptData("snapshot", at, reason))
    try:
        return int(header["version"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CorruptData("snapshot", HEADER_AT, f"bad version: {type(exc).__name__}") from None


def upload_config(data: bytes) -> tuple[bool, dict[str, Any]]:
    """(whether it is a sparse world's snapshot, its configuration), from the header alone: the
    body is checked where the world is made (``sparse_upload``, ``decode_upload``)."""
    header, _ = _read_header(memoryview(data), lambda at, reason: InvalidInput(f"uploaded snapshot: {reason}"))
    sparse = _is_sparse(header, lambda reason: InvalidInput(f"uploaded snapshot: {reason}"))
    try:
        return sparse, dict(header["config"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InvalidInput(f"uploaded snapshot: bad header: {type(exc).__name__}") from None


def sparse_upload(data: bytes, config: Any, max_voxels: int) -> SparseContent:
    """The bricks of a sparse world's snapshot a client sent, for a world of ``config`` (a
    WorldConfig): the file whole and its field exact (``sparse_snapshot.check_upload``), at most
    ``max_voxels`` stored voxels (413); any defect is 422."""
    where = "uploaded sparse snapshot"
    fail = lambda reason: InvalidInput(f"{where}: {reason}")  # noqa: E731
    snap = decode_snapshot(data, where, max_voxels=max_voxels, corrupt=InvalidInput, allow_sparse=True)
    content = snap.voxels
    if not isinstance(content, SparseContent):
        raise fail("a dense world's snapshot; this import makes a sparse world")
    if list(snap.config.get("size", ())) != list(config.size) or content.brick != config.chunk_size:
        raise fail(f"its size {snap.config.get('size')} and brick {content.brick} are not the world's "
                   f"{list(config.size)} and {config.chunk_size}")
    check_upload(content, tuple(config.size), config.max_distance, fail)
    return content


def write_snapshot(directory: Path, version: int, config: dict[str, Any], voxels: np.ndarray) -> Path:
    """Write durably (temporary file, fsync, rename, directory fsync), then drop older ones."""
    path = Path(directory) / snapshot_name(version)
    write_atomic(path, encode_snapshot(version, config, voxels))
    older = [p for p in Path(directory).glob(SNAPSHOT_PATTERN) if snapshot_version(p) < version]
    for p in older:
        p.unlink()
    if older:
        fsync_dir(directory)
    return path


def read_latest_snapshot(directory: Path) -> Snapshot | None:
    """The newest snapshot, or None. A damaged newest snapshot is an error: the log before it
    may have been trimmed, so falling back to an older one could lose acknowledged edits."""
    paths = sorted(Path(directory).glob(SNAPSHOT_PATTERN), key=snapshot_version)
    if not paths:
        return None
    path = paths[-1]
    snap = decode_snapshot(path.read_bytes(), str(path))
    if snap.version != snapshot_version(path):
        raise CorruptData(str(path), None, f"file name says version {snapshot_version(path)}, "
                          f"header says {snap.version}")
    return snap


def remove_snapshot_files(directory: Path) -> None:
    for p in Path(directory).glob(SNAPSHOT_PATTERN):
        os.unlink(p)
