"""Recovery of one world's directory: the latest snapshot plus the log records after it.

Segments are read in the order they were written: by epoch, then base version. Each opening
of a world for writing takes a new epoch (``Storage.open_world``) and starts a segment of that
epoch at the last version it recovered; that segment **fences** the epochs before it: what an
older epoch wrote past its base — an engine that went on writing after its world was taken
over — is ignored, and whole segments of an older epoch that start at or past it are dropped.
Within one epoch segments must chain (each starts where the previous ended); across epochs the
older one must reach the newer one's base.

Segments whose records all precede the snapshot are ignored (and trimmed). The records must
continue the snapshot's version with no gap. A torn tail of an epoch's last segment (a crash
in the middle of an append) is cut there; anything else that is damaged raises
``CorruptData`` naming the file and offset.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sdfserver.errors import CorruptData
from sdfserver.storage.framing import SegmentScan, scan_segment
from sdfserver.storage.fsutil import remove_temporaries
from sdfserver.storage.snapshot import read_latest_snapshot
from sdfserver.storage.wal import SEGMENT_PATTERN, history_order, segment_base, segment_epoch


@dataclass
class Recovered:
    snapshot_version: int  # 0 with ``voxels`` None: an empty world
    voxels: np.ndarray | None  # uint8 (z, y, x) from the snapshot
    records: list[tuple[int, bytes]] = field(default_factory=list)  # (version, payload) after it
    last_version: int = 0
    segment: Path | None = None  # the segment to keep appending to, if it continues the log
    segment_end: int = 0  # its valid length (a torn tail beyond this is truncated)
    torn: str = ""  # what was truncated, for the log
    stale_segments: list[Path] = field(default_factory=list)
    fenced_records: int = 0  # records an older epoch wrote after a newer one took the world over


def recover_world(directory: Path) -> Recovered:
    directory = Path(directory)
    remove_temporaries(directory)
    snap = read_latest_snapshot(directory)
    base = snap.version if snap else 0
    result = Recovered(base, snap.voxels if snap else None, last_version=base)
    written = sorted(directory.glob(SEGMENT_PATTERN), key=history_order)
    segments = _history(written)
    # Segment i holds versions base_i + 1 .. base_{i+1}; it matters only if base_{i+1} > base.
    relevant = [s for s, nxt in zip(segments, segments[1:] + [None])
                if nxt is None or segment_base(nxt) > base]
    result.stale_segments = [s for s in written if s not in relevant]
    if not relevant:
        if snap is None:
            raise CorruptData(str(directory), None, "no snapshot and no log segment")
        return result
    first = segment_base(relevant[0])
    if first > base:
        raise CorruptData(str(relevant[0]), None, f"the log starts after version {first} but the "
                          f"snapshot is at version {base}: versions {base + 1}..{first} are missing")
    scans: list[SegmentScan] = []
    for path, nxt in zip(relevant, relevant[1:] + [None]):
        scan = scan_segment(path.read_bytes(), str(path), segment_base(path))
        handed_over = nxt is not None and segment_epoch(nxt) > segment_epoch(path)
        if scan.torn_at is not None and nxt is not None and not handed_over:
            raise CorruptData(str(path), scan.torn_at, f"bad record ({scan.torn_reason}) in a segment "
                              "that a newer segment follows")
        if nxt is not None:
            end = segment_base(nxt)
            if scan.last_version < end or (scan.last_version > end and not handed_over):
                raise CorruptData(str(path), scan.good_end, f"segment ends at version {scan.last_version} "
                                  f"but the next segment starts after {end}")
            result.fenced_records += sum(1 for r in scan.records if r[0] > end)
            scan.records = [r for r in scan.records if r[0] <= end]
        scans.append(scan)
    for scan in scans:
        result.records.extend(r for r in scan.records if r[0] > base)
    newest, newest_scan = relevant[-1], scans[-1]
    result.last_version = max(base, newest_scan.last_version)
    if newest_scan.torn_at is not None:
        result.torn = (f"{newest}: truncated a torn last record at offset {newest_scan.torn_at} "
                       f"({newest_scan.torn_reason})")
    if newest_scan.last_version == result.last_version:
        result.segment, result.segment_end = newest, newest_scan.good_end
    return result


def _history(segments: list[Path]) -> list[Path]:
    """The segments that make the world's history, in the order written: a segment of a newer
    epoch drops the older epochs' segments that start at or past its base (all they hold is
    fenced)."""
    chain: list[Path] = []
    for path in segments:
        epoch, base = segment_epoch(path), segment_base(path)
        while chain and segment_epoch(chain[-1]) < epoch and segment_base(chain[-1]) >= base:
            chain.pop()
        chain.append(path)
    return chain
