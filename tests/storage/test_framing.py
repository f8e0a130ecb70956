"""Record framing and segment scanning: torn tails are truncated, damage in the middle is refused."""

import random
import struct

import pytest

from sdfserver.errors import CorruptData
from sdfserver.storage.framing import (RECORD_HEADER, SEGMENT_HEADER, encode_record,
                                       encode_segment_header, scan_segment)


def segment(base, payloads):
    frames = [encode_record(base + 1 + i, p) for i, p in enumerate(payloads)]
    offsets, at = [], SEGMENT_HEADER.size
    for f in frames:
        offsets.append(at)
        at += len(f)
    return encode_segment_header(base) + b"".join(frames), offsets


@pytest.fixture
def payloads():
    rng = random.Random()
    return [rng.randbytes(rng.randrange(0, 200)) for _ in range(6)]


def test_round_trip(payloads):
    data, _ = segment(41, payloads)
    scan = scan_segment(data, "seg", 41)
    assert scan.records == [(42 + i, p) for i, p in enumerate(payloads)]
    assert scan.torn_at is None and scan.good_end == len(data) and scan.last_version == 47


def test_every_truncation_of_the_last_record_is_a_torn_tail(payloads):
    data, offsets = segment(0, payloads)
    for cut in range(offsets[-1] + 1, len(data)):
        scan = scan_segment(data[:cut], "seg", 0)
        assert [v for v, _ in scan.records] == [1, 2, 3, 4, 5]
        assert scan.torn_at == offsets[-1] and scan.good_end == offsets[-1]


def test_bad_crc_at_the_tail_and_zero_fill_are_torn(payloads):
    data, offsets = segment(0, payloads)
    damaged = bytearray(data)
    damaged[-1] ^= 0xFF if payloads[-1] else 0
    damaged[offsets[-1] + 12] ^= 0x01  # the CRC field itself
    scan = scan_segment(bytes(damaged), "seg", 0)
    assert scan.torn_at == offsets[-1] and len(scan.records) == 5
    scan = scan_segment(data + bytes(4096), "seg", 0)  # a file extended with zeros by a crash
    assert scan.torn_at == len(data) and len(scan.records) == 6


@pytest.mark.parametrize("field_offset", [0, 4, 12, RECORD_HEADER.size])
def test_damage_in_the_middle_names_file_and_offset(payloads, field_offset):
    payloads[2] = payloads[2] or b"x"
    data, offsets = segment(0, payloads)
    damaged = bytearray(data)
    damaged[offsets[2] + field_offset] ^= 0x40  # length, version, CRC or payload of record 3
    with pytest.raises(CorruptData) as info:
        scan_segment(bytes(damaged), "/data/worlds/w/wal-0.log", 0)
    assert info.value.path == "/data/worlds/w/wal-0.log"
    assert info.value.offset == offsets[2]
    assert f"offset {offsets[2]}" in str(info.value)


def test_a_length_pointing_past_the_end_in_the_middle_is_still_corruption(payloads):
    data, offsets = segment(0, payloads)
    damaged = bytearray(data)
    damaged[offsets[1]:offsets[1] + 4] = struct.pack("<I", 10 ** 9)
    with pytest.raises(CorruptData, match="a valid record follows"):
        scan_segment(bytes(damaged), "seg", 0)


def test_versions_must_be_continuous(payloads):
    frames = [encode_record(v, b"p") for v in (1, 2, 4)]
    with pytest.raises(CorruptData, match="expected 3"):
        scan_segment(encode_segment_header(0) + b"".join(frames), "seg", 0)
    with pytest.raises(CorruptData, match="expected 8"):
        scan_segment(encode_segment_header(7) + encode_record(9, b"p"), "seg", 7)


def test_bad_header():
    with pytest.raises(CorruptData, match="magic"):
        scan_segment(b"NOTAWAL!" + bytes(8), "seg")
    with pytest.raises(CorruptData, match="segment header"):
        scan_segment(b"SDF", "seg")
    with pytest.raises(CorruptData, match="file name says 3"):
        scan_segment(encode_segment_header(5), "seg", 3)
