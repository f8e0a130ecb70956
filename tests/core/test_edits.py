"""Edits on the device match a NumPy replay; bad batches raise and change nothing."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from sdfserver.edits import BoxEdit, EditLimits, SphereEdit, VoxelsEdit, edit_bounds, parse_edits
from sdfserver.errors import InvalidEdit, TooLarge
from sdfserver.world import SMALL_DIRTY_CHUNKS, World, WorldConfig

from .conftest import oracle


def replay(voxels: np.ndarray, edits) -> np.ndarray:
    """An independent NumPy model of the edit semantics."""
    out = voxels.copy()
    sz, sy, sx = out.shape
    z, y, x = np.indices(out.shape)
    for e in edits:
        if isinstance(e, VoxelsEdit):
            for vx, vy, vz, c in e.voxels:  # test oracle: tiny lists
                out[vz, vy, vx] = c
        elif isinstance(e, BoxEdit):
            (x0, y0, z0), (x1, y1, z1) = e.min, e.max
            out[max(z0, 0):max(z1, 0), max(y0, 0):max(y1, 0), max(x0, 0):max(x1, 0)] = e.colour
        else:
            c = np.asarray(e.center, np.float32)
            d2 = (x - c[0]).astype(np.float32) ** 2 + (y - c[1]).astype(np.float32) ** 2 + (z - c[2]).astype(np.float32) ** 2
            out[d2 <= np.float32(e.radius * e.radius)] = e.colour
    return out


def test_batch_applies_in_order_and_later_duplicates_win(gpu):
    world = World(gpu, WorldConfig((16, 16, 16), 8, 255))
    try:
        edits = [
            BoxEdit((2, 2, 2), (10, 6, 9), 40),
            SphereEdit((8.0, 8.0, 8.0), 3.5, 0),
            VoxelsEdit(np.array([[1, 1, 1, 5], [1, 1, 1, 6], [15, 15, 15, 200]])),
        ]
        assert world.apply_edits(edits) == 1
        expected = replay(np.zeros((16, 16, 16), np.uint8), edits)
        assert np.array_equal(world.read_voxels(), expected)
        assert world.read_voxels()[1, 1, 1] == 6
    finally:
        world.release()


BAD_BATCHES = [
    ([], InvalidEdit),
    ([VoxelsEdit(np.array([[0, 0, 16, 3]]))], InvalidEdit),  # z out of bounds
    ([VoxelsEdit(np.array([[-1, 0, 0, 3]]))], InvalidEdit),
    ([VoxelsEdit(np.array([[0, 0, 0, 256]]))], InvalidEdit),
    ([VoxelsEdit(np.zeros((0, 4), np.int64))], InvalidEdit),
    ([BoxEdit((4, 4, 4), (2, 8, 8), 1)], InvalidEdit),
    ([SphereEdit((1.0, 1.0, 1.0), 1e6, 1)], InvalidEdit),
    ([SphereEdit((1.0, 1.0, 1.0), 2.0, 1)] * 9, TooLarge),
    ([VoxelsEdit(np.zeros((65, 4), np.int64))], TooLarge),
]


@pytest.mark.parametrize("batch,error", BAD_BATCHES)
def test_bad_batch_changes_nothing(gpu, rng, batch, error):
    limits = EditLimits(max_ops_per_batch=8, max_voxels_per_batch=64, max_brush_radius_vox=32)
    world = World(gpu, WorldConfig((16, 16, 16), 8, 255), limits)
    try:
        # A valid first op in front of the bad ones: nothing of the batch may apply.
        world.apply_edits([BoxEdit((0, 0, 0), (16, 4, 16), 9)])
        world.recompute()
        before_voxels, before_field = world.read_voxels(), world.read_field()
        with pytest.raises(error):
            world.apply_edits([BoxEdit((0, 8, 0), (16, 9, 16), 3), *batch] if batch else batch)
        assert world.version == 1
        assert world.dirty_chunk_count == 0
        world.recompute()
        assert np.array_equal(world.read_voxels(), before_voxels)
        assert np.array_equal(world.read_field(), before_field)
    finally:
        world.release()


@pytest.mark.parametrize("raw,message", [
    ("not a list", "must be a list"),
    ([{"op": "teleport"}], "unknown op"),
    ([{"op": "box", "min": [0, 0, 0], "max": [1, 1, 1]}], "missing field 'colour'"),
    ([{"op": "box", "min": [0, 0, 0], "max": [1, 1, 1], "colour": "red"}], "colour"),
    ([{"op": "box", "min": [0, 0, 0], "max": [1, 1, 1], "colour": True}], "colour"),
    ([{"op": "box", "min": [0, 0.5, 0], "max": [1, 1, 1], "colour": 1}], "integers"),
    ([{"op": "sphere", "center": [0, float("nan"), 0], "radius": 1, "colour": 1}], "finite"),
    ([{"op": "sphere", "center": [0, 0, 0], "radius": float("inf"), "colour": 1}], "finite"),
    ([{"op": "voxels", "voxels": [[1, 2, 3]]}], "[x, y, z, colour]"),
    ([{"op": "voxels", "voxels": np.zeros((2, 4), np.float32)}], "integer"),
])
def test_parse_rejects_malformed_edits(raw, message):
    with pytest.raises(InvalidEdit, match=message.replace("[", r"\[").replace("]", r"\]")):
        parse_edits(raw)


coord = st.integers(0, 15)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    initial=st.lists(st.tuples(coord, coord, coord, st.integers(1, 255)), max_size=12),
    edits=st.lists(st.tuples(coord, coord, coord, st.integers(0, 255)), min_size=1, max_size=8),
    cap=st.integers(1, 30),
)
def test_small_worlds_incremental_matches_oracle(gpu, initial, edits, cap):
    """Hypothesis: tiny worlds, random place/erase voxel edits, incremental == oracle."""
    size = (16, 16, 16)
    world = World(gpu, WorldConfig(size, 8, cap))
    try:
        voxels = np.zeros(size[::-1], np.uint8)
        if initial:
            batch = VoxelsEdit(np.array(initial))
            world.apply_edits([batch])
            voxels = replay(voxels, [batch])
        world.recompute()
        batch = VoxelsEdit(np.array(edits))
        world.apply_edits([batch])
        voxels = replay(voxels, [batch])
        world.recompute()
        assert np.array_equal(world.read_voxels(), voxels)
        assert np.array_equal(world.read_distance(), oracle(voxels, cap))
    finally:
        world.release()


def test_dirty_chunk_count_is_the_chunks_the_brushes_touch(gpu, rng):
    """A step's dirty chunks are counted in a set when they are few and with the chunk mask
    otherwise; both must give the chunks the brushes' boxes touch, overlaps counted once."""
    world = World(gpu, WorldConfig((128, 128, 96), 8, 16), EditLimits(max_brush_radius_vox=64))
    try:
        # the last: over 4,096 (chunk, brush) pairs, so its centres stay clear of the world's faces
        for brushes, radius, lo, hi in ((2, 3.0, 0, 96), (7, 5.0, 0, 96), (3, 60.0, 36, 60)):
            edits = [SphereEdit(tuple(float(v) for v in rng.uniform(lo, hi, 3)), radius, 1) for _ in range(brushes)]
            for edit in edits:
                world.apply_edits([edit])
            expected = np.zeros(world.config.chunks[::-1], dtype=bool)
            for box in world.dirty.boxes:
                expected[box.chunk_range(8).slices_zyx()] = True
            pairs = sum(box.chunk_range(8).volume for box in world.dirty.boxes)
            assert (pairs > SMALL_DIRTY_CHUNKS) == (radius == 60.0)  # both ways of counting are exercised
            assert world.dirty_chunk_count == int(expected.sum())
            world.recompute()
            assert world.dirty_chunk_count == 0
    finally:
        world.release()


@pytest.mark.parametrize("brushes", [40, 300])  # 300: more than one fill_brushes launch
def test_many_overlapping_brushes_in_order(gpu, rng, brushes):
    """Box and sphere edits across several batches go to the device together (fill_brushes);
    where they overlap the later one must win, a voxels edit between them must keep its place,
    and the field must still match the oracle."""
    world = World(gpu, WorldConfig((40, 24, 32), 8, 12))
    try:
        batches, flat = [], []
        for b in range(4):
            batch = []
            for _ in range(brushes // 4):
                colour = int(rng.choice([0, int(rng.integers(1, 256))], p=[0.3, 0.7]))
                if rng.random() < 0.5:
                    lo = rng.integers(-4, 36, 3)
                    batch.append(BoxEdit(tuple(int(v) for v in lo), tuple(int(v) for v in lo + rng.integers(1, 12, 3)),
                                         colour))
                else:
                    center = tuple(float(v) for v in rng.integers(0, 40, 3))
                    batch.append(SphereEdit(center, float(rng.integers(1, 8)) + 0.5, colour))
            if b == 2:  # explicit voxels in the middle of the brushes
                batch.insert(len(batch) // 2, VoxelsEdit(np.array([[x, 5, 7, 200] for x in range(0, 40, 3)])))
            batches.append(batch)
            flat.extend(batch)
        versions = world.apply_plans([world.plan_edits(batch) for batch in batches])
        assert versions == [1, 2, 3, 4]
        world.recompute()
        voxels = world.read_voxels()
        np.testing.assert_array_equal(voxels, replay(np.zeros_like(voxels), flat))
        np.testing.assert_array_equal(world.read_distance(), oracle(voxels, 12))
    finally:
        world.release()


def exact_sphere(dims, centre, radius) -> np.ndarray:
    """Voxels with |p - centre| <= radius in exact arithmetic on the given floats, (z, y, x)."""
    c, r2 = [Fraction(v) for v in centre], Fraction(radius) ** 2
    inside = np.zeros(dims[::-1], bool)
    for z, y, x in np.ndindex(*inside.shape):
        inside[z, y, x] = (x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2 <= r2
    return inside


@settings(max_examples=200, deadline=None)
@given(dims=st.tuples(*[st.integers(1, 10)] * 3),
       sphere=st.booleans(),
       a=st.tuples(*[st.integers(-6, 16)] * 3),
       b=st.tuples(*[st.integers(-6, 16)] * 3),
       centre=st.tuples(*[st.floats(-8, 20, allow_nan=False)] * 3),
       radius=st.floats(0, 9, allow_nan=False))
def test_edit_bounds_hold_every_voxel_a_brush_covers(dims, sphere, a, b, centre, radius):
    """The engine launches a brush over edit_bounds and marks only it dirty: it must hold every
    voxel the brush covers (a sphere's in exact arithmetic), inside the world, and for a box
    nothing more."""
    if sphere:
        edit, covers = SphereEdit(centre, radius, 1), exact_sphere(dims, centre, radius)
    else:
        edit = BoxEdit(a, tuple(map(max, a, b)), 1)
        covers = replay(np.zeros(dims[::-1], np.uint8), [edit]) != 0
    boxes = edit_bounds(edit, dims, 4)
    assert len(boxes) <= 1
    bounded = np.zeros_like(covers)
    for box in boxes:
        assert all(0 <= lo < hi <= d for lo, hi, d in zip(box.lo, box.hi, dims))
        bounded[box.slices_zyx()] = True
    assert not (covers & ~bounded).any()
    if not sphere:
        assert np.array_equal(covers, bounded)
