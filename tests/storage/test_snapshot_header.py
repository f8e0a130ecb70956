"""A snapshot header's format decides how its body is read: format 1 (dense voxels) and format 2
(a sparse world's bricks) only. Any other, or the numbers' look-alikes (true, 1.0, "1"), is
refused before the body is touched, on disk and in an upload alike."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from sdfserver.errors import CorruptData, InvalidInput
from sdfserver.storage.snapshot import HEADER_AT, SNAPSHOT_MAGIC, decode_snapshot, encode_snapshot, upload_config

CONFIG = {"size": [8, 8, 8], "chunk_size": 8, "max_distance": 16}


def snapshot_with(**changes) -> bytes:
    voxels = np.zeros((8, 8, 8), np.uint8)
    voxels[:4, :4, :4] = 9
    data = encode_snapshot(3, CONFIG, voxels)
    (length,) = struct.unpack_from("<I", data, len(SNAPSHOT_MAGIC))
    header = {**json.loads(data[HEADER_AT:HEADER_AT + length]), **changes}
    encoded = json.dumps(header).encode()
    return SNAPSHOT_MAGIC + struct.pack("<I", len(encoded)) + encoded + data[HEADER_AT + length:]


def test_a_format_1_snapshot_reads_back():
    assert int(decode_snapshot(snapshot_with()).voxels.sum()) == 64 * 9
    assert upload_config(snapshot_with()) == (False, CONFIG)


@pytest.mark.parametrize("fmt", [2, 3, 0, -1, True, 1.0, "1", None, [1]])
def test_any_other_format_is_refused_on_disk_and_in_an_upload(fmt):
    data = snapshot_with(format=fmt)
    with pytest.raises(CorruptData, match="unsupported format"):
        decode_snapshot(data, "snap-3.sdfsnap")
    with pytest.raises(InvalidInput, match="unsupported format"):
        upload_config(data)


def test_format_2_with_a_dense_body_is_refused():
    with pytest.raises(CorruptData, match="unsupported format"):
        decode_snapshot(snapshot_with(format=2), "snap-3.sdfsnap")
    with pytest.raises(CorruptData):  # the header says bricks, the body is voxels: its layout fails
        decode_snapshot(snapshot_with(format=2, dtype="bricks"), "snap-3.sdfsnap")
