"""The engine thread's shortcuts give what the general code gives: the dirty set's regions when
one box grows to the whole world, a box's chunk range and the changed-chunk count, kernel times
read straight from an event, a log record framed in one pass, a sphere parsed without its error
texts."""

from __future__ import annotations

import math
import random
import struct
import zlib

import pyopencl as cl
import pytest

from sdfserver.dirty import DirtySet
from sdfserver.edits import parse_edit
from sdfserver.errors import InvalidEdit
from sdfserver.geometry import Box, merge_regions
from sdfserver.gpu.profiling import event_ms
from sdfserver.storage.framing import encode_record
from sdfserver.world import RecomputeResult, WorldConfig


def _random_box(rng: random.Random, size: tuple[int, int, int]) -> Box:
    lo = tuple(rng.randrange(s) for s in size)
    return Box(lo, tuple(min(s, v + rng.randrange(1, 12)) for v, s in zip(lo, size)))


def _reference_regions(boxes: list[Box], config: WorldConfig) -> list[Box]:
    cap = 0 if config.borders == "padded" else config.max_distance
    world = Box.of_size(config.size)
    return merge_regions([b.grow(cap).snap(config.chunk_size).intersect(world) for b in boxes])


def test_dirty_regions_match_grow_snap_clip_merge():
    rng = random.Random()
    for _ in range(300):
        size = tuple(rng.choice((16, 48, 64, 128)) for _ in range(3))
        config = WorldConfig(size=size, chunk_size=rng.choice((8, 16)),
                             max_distance=rng.choice((0, 3, 16, 40, 64, 255)),
                             borders=rng.choice(("exact", "padded")), algorithm="brute")
        dirty = DirtySet()
        dirty.add([_random_box(rng, size) for _ in range(rng.randrange(1, 20))])
        assert sorted(dirty.regions(config), key=str) == sorted(_reference_regions(dirty.boxes, config), key=str)


def test_one_box_growing_to_the_whole_world_gives_the_whole_world():
    config = WorldConfig(size=(64, 48, 32), chunk_size=16, max_distance=40)
    dirty = DirtySet()
    dirty.add([Box((20, 20, 10), (22, 22, 12)), Box((0, 0, 0), (1, 1, 1))])
    assert dirty.regions(config) == [Box((0, 0, 0), (64, 48, 32))]
    near_corner = DirtySet()  # grows to the world's far side only past a chunk boundary: not all of it
    near_corner.add([Box((0, 0, 0), (1, 1, 1))])
    assert near_corner.regions(config) == [Box((0, 0, 0), (48, 48, 32))]
    one_chunk_short = DirtySet()  # reaches every side but x's low one, by one chunk
    one_chunk_short.add([Box((56, 0, 0), (57, 1, 1))])
    assert one_chunk_short.regions(config) == [Box((16, 0, 0), (64, 48, 32))]


def _chunks_touched(box: Box, chunk: int) -> list[set[int]]:
    """Per axis, the chunk index of every voxel the box holds."""
    return [{v // chunk for v in range(lo, hi)} for lo, hi in zip(box.lo, box.hi)]


def test_chunk_range_and_changed_chunk_count_are_the_chunks_the_voxels_fall_in():
    rng = random.Random()
    for _ in range(100):
        size = (128, 128, 128)
        chunk = rng.choice((8, 16, 32))
        regions = [_random_box(rng, size) for _ in range(rng.randrange(0, 5))]
        for region in regions:
            touched = _chunks_touched(region, chunk)
            assert region.chunk_range(chunk) == Box(tuple(min(t) for t in touched), tuple(max(t) + 1 for t in touched))
        expected = sum(math.prod(len(t) for t in _chunks_touched(r, chunk)) for r in regions)
        assert RecomputeResult(regions, chunk).changed_chunk_count == expected


def test_event_ms_of_a_real_event_is_its_profiled_time(gpu):
    event = cl.enqueue_marker(gpu.queue)
    gpu.queue.finish()
    assert event_ms(event) == (event.profile.end - event.profile.start) * 1e-6


def test_a_record_is_length_version_crc_payload():
    head = struct.pack("<IQ", 7, 9)
    assert encode_record(9, b"payload") == head + struct.pack("<I", zlib.crc32(head + b"payload")) + b"payload"
    assert encode_record(1, b"") == struct.pack("<IQI", 0, 1, zlib.crc32(struct.pack("<IQ", 0, 1)))


class _Wire(dict):
    """A dict the parser's shortcut does not take: the general path."""


def _outcome(raw: dict):
    try:
        edit = parse_edit(raw, 3)
    except InvalidEdit as exc:
        return "error", str(exc)
    return type(edit), edit, [type(v) for v in edit.center], type(edit.radius), type(edit.colour)


def test_a_sphere_parses_as_the_general_path_parses_it():
    rng = random.Random()
    odd = [math.inf, -math.inf, math.nan, True, 7, 1 << 70, "3", None, 2.5, -0.0, 1e300]
    for _ in range(2000):
        raw = {"op": "sphere", "center": [rng.uniform(-50, 300) for _ in range(3)],
               "radius": rng.uniform(0, 20), "colour": rng.randrange(0, 256)}
        if rng.random() < 0.6:
            field = rng.choice(("center", "radius", "colour", "x"))
            if field == "center":
                raw["center"] = rng.choice(([1.0, 2.0], (1.0, 2.0, 3.0), [1.0, 2.0, rng.choice(odd)], "abc"))
            elif field == "x":
                raw.pop(rng.choice(("center", "radius", "colour")))
            else:
                raw[field] = rng.choice(odd + [256, -1, 255, 0])
        assert _outcome(raw) == _outcome(_Wire(raw)), raw


def _hostile_value(rng: random.Random, depth: int = 0):
    """Something a client might put where a number or a triple goes."""
    choice = rng.randrange(14)
    if choice < 3:
        return rng.randrange(-300, 300)
    if choice < 5:
        return rng.uniform(-300, 300)
    if choice == 5:
        return rng.choice((math.nan, math.inf, -math.inf, 2 ** 63, -2 ** 63, 2 ** 64 - 1))
    if choice == 6:
        return rng.choice((True, False, None, "7", b"7", 1.0))
    if depth < 2:
        return [_hostile_value(rng, depth + 1) for _ in range(rng.choice((2, 3, 3, 3, 4)))]
    return rng.randrange(256)


def _hostile_op(rng: random.Random) -> list[tuple]:
    """A box's or a sphere's map as (key, value) pairs, in any order: well formed, or with one
    value made hostile, a key missing, an extra or repeated key, or another op."""
    if rng.random() < 0.5:
        pairs = [("op", "sphere"), ("center", [rng.uniform(-9, 40) for _ in range(3)]),
                 ("radius", rng.choice((rng.randrange(0, 30), rng.uniform(0, 30)))), ("colour", rng.randrange(256))]
    else:
        pairs = [("op", "box"), ("min", [rng.randrange(-5, 30) for _ in range(3)]),
                 ("max", [rng.randrange(-5, 40) for _ in range(3)]), ("colour", rng.randrange(256))]
    harm = rng.randrange(8)
    if harm == 0:  # one value, or one coordinate of a triple
        k = rng.randrange(1, 4)
        name, value = pairs[k]
        if isinstance(value, list) and rng.random() < 0.7:
            value = list(value)
            value[rng.randrange(3)] = _hostile_value(rng, 2)
        else:
            value = _hostile_value(rng)
        pairs[k] = (name, value)
    elif harm == 1:
        pairs.pop(rng.randrange(len(pairs)))
    elif harm == 2:
        pairs.append((rng.choice(("extra", "op", "radius", "colour", "min", "center")), _hostile_value(rng)))
    elif harm == 3:
        pairs[0] = ("op", rng.choice(("voxels", "cone", 5, "box" if pairs[0][1] == "sphere" else "sphere")))
    rng.shuffle(pairs)
    return pairs


def _packed_map(pairs: list[tuple]) -> bytes:
    """A msgpack map written pair by pair, so that a key may appear twice."""
    import msgpack

    return bytes([0x80 | len(pairs)]) + b"".join(msgpack.packb(k) + msgpack.packb(v) for k, v in pairs)


def test_brushes_decoded_in_one_call_are_what_parse_edits_makes_of_the_record():
    """decode_brushes takes a record only where the general path (codec.decode_batch,
    batch_parts, parse_edits) gives the same edits of the same types and the same batch id: the
    engine applies what replaying the log would apply. Records it does not take go that path."""
    import msgpack

    from sdfserver.edits import BoxEdit, SphereEdit, decode_brushes, parse_edits
    from sdfserver.storage.codec import batch_parts, decode_batch

    rng = random.Random()
    taken = refused_alike = 0
    for _ in range(3000):
        ops = [_hostile_op(rng) for _ in range(rng.choice((0, 1, 1, 2, 3)))]
        edits = bytes([0x90 | len(ops)]) + b"".join(_packed_map(op) for op in ops)
        payload = edits if rng.random() < 0.7 else (
            _packed_map([("batch_id", rng.choice(("k1", 7))), ("edits", msgpack.unpackb(edits, strict_map_key=False))]
                        + ([("more", 1)] if rng.random() < 0.2 else [])))
        fast = decode_brushes(payload)
        try:
            wire, batch_id = batch_parts(decode_batch(payload))
            general = (parse_edits(wire), batch_id)
        except Exception:
            general = None
        if fast is None:
            refused_alike += general is None
            continue
        taken += 1
        assert general is not None, (payload, fast)
        assert fast[1] == general[1]
        assert len(fast[0]) == len(general[0])
        for a, b in zip(fast[0], general[0]):
            assert type(a) is type(b) and type(a) in (BoxEdit, SphereEdit)
            assert a == b, (payload, a, b)
    assert taken > 500 and refused_alike > 100


def test_brushes_planned_in_one_pass_are_what_validation_and_edit_bounds_give():
    """plan_brushes gives, for a batch it takes, the boxes edit_bounds gives after validate_batch
    passed; a batch it does not take is one validate_batch refuses, or one it has no shortcut for
    (voxels, numpy colours), under the limits of clients and of replay."""
    import numpy as np

    from sdfserver.edits import (
        REPLAY_LIMITS, BoxEdit, EditLimits, SphereEdit, VoxelsEdit, edit_bounds, plan_brushes, validate_batch,
    )
    from sdfserver.errors import SdfServerError

    rng = random.Random()
    taken = refused = 0
    for _ in range(4000):
        dims = (8, 8, 8) if rng.random() < 0.3 else tuple(rng.choice((8, 16, 40, 64)) for _ in range(3))
        limits = rng.choice((EditLimits(), REPLAY_LIMITS, EditLimits(max_ops_per_batch=2, max_brush_radius_vox=6.0,
                                                                      max_coordinate_vox=50, max_brush_voxels_per_batch=900)))

        def coordinate() -> float:
            return rng.choice((rng.uniform(-20, 80), rng.randrange(-20, 80), rng.choice((-2 ** 31 - 1, 2 ** 31, 51, -51))))

        edits = []
        for _ in range(rng.choice((0, 1, 1, 2, 3))):
            colour = rng.choice((rng.randrange(256), rng.randrange(256), 255, 256, -1, np.int64(7)))
            if rng.random() < 0.5:
                edits.append(SphereEdit(tuple(float(coordinate()) for _ in range(3)),
                                        rng.choice((rng.uniform(0, 12), float(rng.randrange(0, 12)), -1.0, 300.0)), colour))
            elif rng.random() < 0.9:
                near = rng.random() < 0.4  # over much of the world: the batch's voxel limit
                lo = [rng.randrange(-3, 3) if near else int(coordinate()) for _ in range(3)]
                edits.append(BoxEdit(tuple(lo), tuple(v + rng.randrange(5 if near else -2, 30) for v in lo), colour))
            else:
                edits.append(VoxelsEdit(np.array([[1, 2, 3, 4]], dtype=np.int64)))
        planned = plan_brushes(edits, dims, limits)
        try:
            validate_batch(edits, dims, limits)
            general = [edit_bounds(e, dims, 8) for e in edits]
        except SdfServerError:
            general = None
        if planned is None:
            refused += general is None
            continue
        taken += 1
        assert planned == general, (edits, dims, planned, general)
    assert taken > 150 and refused > 500
    # the batch's voxel limit, which random batches rarely reach: the world once is always allowed
    small, whole = EditLimits(max_brush_voxels_per_batch=900), BoxEdit((0, 0, 0), (8, 8, 8), 1)
    assert plan_brushes([whole], (8, 8, 8), small) == [[Box((0, 0, 0), (8, 8, 8))]]
    assert plan_brushes([whole, whole], (8, 8, 8), small) is None
    with pytest.raises(SdfServerError, match="1,024 voxels"):
        validate_batch([whole, whole], (8, 8, 8), small)
