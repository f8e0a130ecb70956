"""Log segment framing: how records sit in a file, and how a file is read back.

A segment file is a 16-byte header — magic ``SDFWAL01`` and the segment's base version
(u64, little endian) — followed by records. A segment with base ``b`` holds versions
``b + 1, b + 2, ...`` with no gaps. A record is::

    u32 payload length | u64 version | u32 crc32(length, version, payload) | payload

``scan_segment`` reads a whole segment and tells apart the two ways a file can be damaged:

* a **torn tail** — the last record is short or fails its CRC and nothing valid follows it:
  what a crash in the middle of an append leaves. The caller truncates it.
* **corruption in the middle** — a bad record followed by a valid one, a valid record with
  the wrong version, or a bad header. Data that was acknowledged may be lost here, so this
  raises ``CorruptData`` naming the file and the offset; it never drops records silently.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from sdfserver.errors import CorruptData

SEGMENT_MAGIC = b"SDFWAL01"
SEGMENT_HEADER = struct.Struct("<8sQ")
RECORD_HEADER = struct.Struct("<IQI")
_LENGTH_VERSION = struct.Struct("<IQ")
MAX_RECORD_BYTES = 1 << 30
_SCAN_BLOCK = 1 << 20


def encode_segment_header(base_version: int) -> bytes:
    return SEGMENT_HEADER.pack(SEGMENT_MAGIC, base_version)


def record_crc(length_version: bytes, payload: bytes | memoryview) -> int:
    return zlib.crc32(payload, zlib.crc32(length_version))


def encode_record(version: int, payload: bytes) -> bytes:
    length = len(payload)
    if length > MAX_RECORD_BYTES:
        raise ValueError(f"a log record holds at most {MAX_RECORD_BYTES} bytes, got {length}")
    crc = record_crc(_LENGTH_VERSION.pack(length, version), payload)
    return RECORD_HEADER.pack(length, version, crc) + payload


@dataclass
class SegmentScan:
    base_version: int
    records: list[tuple[int, bytes]] = field(default_factory=list)
    good_end: int = SEGMENT_HEADER.size  # byte offset just past the last valid record
    torn_at: int | None = None  # offset where a torn tail starts, if any
    torn_reason: str = ""

    @property
    def last_version(self) -> int:
        return self.records[-1][0] if self.records else self.base_version


def record_at(data: memoryview, offset: int) -> tuple[int, int, str]:
    """(version, end offset, "") for a valid record at ``offset``, else (0, 0, why not)."""
    if len(data) - offset < RECORD_HEADER.size:
        return 0, 0, f"{len(data) - offset} bytes left, too short for a record header"
    length, version, crc = RECORD_HEADER.unpack_from(data, offset)
    end = offset + RECORD_HEADER.size + length
    if end > len(data):
        return 0, 0, f"record declares {length} payload bytes but the file ends {end - len(data)} bytes early"
    payload = data[offset + RECORD_HEADER.size:end]
    if record_crc(data[offset:offset + 12], payload) != crc:
        return 0, 0, "CRC mismatch"
    return version, end, ""


def _valid_record_after(data: memoryview, start: int, min_version: int) -> int | None:
    """Offset of the first valid record beginning after ``start`` whose version is at least
    ``min_version``, or None. Candidates are filtered with NumPy (plausible length and
    version at every byte offset, a block at a time); only those are CRC-checked."""
    n = len(data)
    raw = np.frombuffer(data, dtype=np.uint8)
    max_version = min_version + (n - start) // RECORD_HEADER.size + 1
    last = n - RECORD_HEADER.size  # the last offset a header fits at
    for first in range(start + 1, last + 1, _SCAN_BLOCK):  # one loop over 1 MiB blocks
        count = min(_SCAN_BLOCK, last + 1 - first)
        def little_endian(at: int, width: int) -> np.ndarray:
            """The unsigned integer at byte ``at`` of every candidate header in this block."""
            return sum(raw[first + at + k:first + at + k + count].astype(np.uint64) << np.uint64(8 * k)
                       for k in range(width))
        length, version = little_endian(0, 4), little_endian(4, 8)
        ends = np.arange(first + RECORD_HEADER.size, first + RECORD_HEADER.size + count,
                         dtype=np.uint64) + length
        plausible = ((ends <= np.uint64(n)) & (version >= np.uint64(min_version))
                     & (version <= np.uint64(max_version)))
        for candidate in np.flatnonzero(plausible):  # CRC-check plausible headers only
            offset = first + int(candidate)
            if record_at(data, offset)[2] == "":
                return offset
    return None


def scan_segment(data: bytes, path: str, expected_base: int | None = None) -> SegmentScan:
    """Read every record of one segment; see the module docstring for what raises."""
    view = memoryview(data)
    if len(view) < SEGMENT_HEADER.size:
        raise CorruptData(path, 0, f"segment header is {len(view)} bytes, expected {SEGMENT_HEADER.size}")
    magic, base = SEGMENT_HEADER.unpack_from(view, 0)
    if magic != SEGMENT_MAGIC:
        raise CorruptData(path, 0, f"bad segment magic {magic!r}")
    if expected_base is not None and base != expected_base:
        raise CorruptData(path, 8, f"segment header says base version {base}, file name says {expected_base}")
    scan = SegmentScan(base)
    offset = SEGMENT_HEADER.size
    expected = base + 1
    while offset < len(view):
        version, end, why = record_at(view, offset)
        if why:
            later = _valid_record_after(view, offset, expected)
            if later is not None:
                raise CorruptData(path, offset, f"bad record ({why}) expected version {expected}, "
                                  f"but a valid record follows at offset {later}; refusing to drop it")
            scan.torn_at, scan.torn_reason = offset, why
            break
        if version != expected:
            raise CorruptData(path, offset, f"record has version {version}, expected {expected} "
                              "(versions must be continuous)")
        scan.records.append((version, bytes(view[offset + RECORD_HEADER.size:end])))
        offset = scan.good_end = end
        expected += 1
    return scan
