"""Edits that only add solids lower the field around them (algorithms/lower.py, kernels/lower.cl):
the field equals a full recompute and scipy's taxicab transform, across chunk borders and world
faces, under small and large caps; an erasing edit, or a world the lowering is not for, takes the
full transform. The worlds here are small, so each test but the threshold's lowers whatever the
size of the regions (``LOWER_ABOVE_REGION_VOXELS`` 0)."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver.algorithms import lower
from sdfserver.edits import parse_edits
from sdfserver.field_values import distances
from sdfserver.world import World, WorldConfig
from sdfserver.world_config import Focus

from references import apply_edits as apply_reference
from references import field_distances, oracle_distance


@pytest.fixture(autouse=True)
def lower_any_region(request, monkeypatch):
    if "threshold" not in request.node.name:
        monkeypatch.setattr(lower, "LOWER_ABOVE_REGION_VOXELS", 0)


def adding_batch(rng, size, colour_low: int = 1) -> list[dict]:
    lo = [int(rng.integers(-3, s)) for s in size]
    return [
        {"op": "sphere", "center": [float(rng.uniform(-4, s + 4)) for s in size],
         "radius": float(rng.uniform(0.5, 7)), "colour": int(rng.integers(colour_low, 256))},
        {"op": "box", "min": lo, "max": [v + int(rng.integers(0, 10)) for v in lo],
         "colour": int(rng.integers(colour_low, 256))},
        # on chunk faces and the world's faces
        {"op": "voxels", "voxels": np.column_stack([
            rng.choice([0, 7, 8, 15, 16, size[0] - 1], 6), rng.integers(0, size[1], 6),
            rng.choice([0, 8, size[2] - 1], 6), rng.integers(colour_low, 256, 6)])},
    ]


def scattered_world(gpu, rng, cap: int, solids: int, **config):
    """A world of random size with ``solids`` random solid voxels, recomputed, and its voxels."""
    size = tuple(int(v) * 8 for v in rng.integers(3, 8, 3))
    world = World(gpu, WorldConfig(size=size, chunk_size=8, max_distance=cap, **config))
    expected = np.zeros(size[::-1], np.uint8)
    first = [{"op": "voxels", "voxels": np.column_stack([rng.integers(0, min(size), (solids, 3)),
                                                         rng.integers(1, 256, solids)])}]
    world.apply_edits(parse_edits(first))
    apply_reference(expected, first)
    world.recompute()
    return world, size, expected


@pytest.mark.parametrize("cap", [2, 9, 40, 255])
def test_adding_solids_lowers_the_field_exactly(gpu, cap):
    rng = np.random.default_rng()
    world, size, expected = scattered_world(gpu, rng, cap, 40)
    try:
        for _ in range(4):
            batch = adding_batch(rng, size)
            world.apply_edits(parse_edits(batch))
            apply_reference(expected, batch)
            assert world._lowering_boxes() is not None, "an adding batch of small boxes is lowered"
            world.recompute()
            field = world.read_field()
            assert np.array_equal(field & 0xFF, expected), "each voxel's own colour"
            assert np.array_equal(distances(field, world.config, expected), oracle_distance(expected, cap))
    finally:
        world.release()


@pytest.mark.parametrize("cap", [2, 9, 40, 255])
def test_erasing_and_mixed_batches_transform_only_where_the_field_can_rise(gpu, cap):
    """A batch that erases transforms the box of the voxels whose nearest solid may have been
    removed (raise_bounds), then lowers around what it added: exact after batches that erase,
    add, or both, over chunk and world faces."""
    rng = np.random.default_rng()
    world, size, expected = scattered_world(gpu, rng, cap, 300)
    try:
        for step in range(6):
            solids = np.argwhere(expected > 0)[rng.permutation(int((expected > 0).sum()))[:4]]  # (z, y, x)
            batch = adding_batch(rng, size, colour_low=0) + [
                {"op": "voxels", "voxels": [[int(x), int(y), int(z), 0] for z, y, x in solids]}]
            if step % 2:  # erasing alone
                batch = batch[-1:] + [{"op": "sphere", "center": [float(v) for v in rng.uniform(0, size)],
                                       "radius": float(rng.uniform(1, 5)), "colour": 0}]
            world.apply_edits(parse_edits(batch))
            apply_reference(expected, batch)
            assert world.dirty.erased and world._lowering_boxes() is not None
            world.recompute()
            field = world.read_field()
            assert np.array_equal(field & 0xFF, expected)
            assert np.array_equal(distances(field, world.config, expected), oracle_distance(expected, cap)), step
    finally:
        world.release()


@pytest.mark.parametrize("cap", [4, 255])
def test_a_euclidean_world_that_only_erased_transforms_its_last_stage_where_it_can_rise(gpu, cap, monkeypatch):
    """Erasing alone: the last stage runs over the box where the field can rise (raise_bounds in
    squared distances), the x and second stages over the edits' boxes as always; exact against
    scipy, and the stages stay current for the lowering after it."""
    import sdfserver.small_edits as small_edits

    calls = []
    real = small_edits.raise_bounds
    monkeypatch.setattr(small_edits, "raise_bounds",
                        lambda *a, **k: calls.append(k.get("euclidean")) or real(*a, **k))
    rng = np.random.default_rng()
    size = tuple(int(v) * 8 for v in rng.integers(3, 6, 3))
    world = World(gpu, WorldConfig(size=size, chunk_size=8, max_distance=cap, metric="euclidean"))
    try:
        expected = np.zeros(size[::-1], np.uint8)

        def step(batch):
            world.apply_edits(parse_edits(batch))
            apply_reference(expected, batch)
            world.recompute()
            got = distances(world.read_field(), world.config, expected)
            assert np.allclose(got, field_distances(expected, "euclidean", False, cap), atol=1e-4)

        step([{"op": "voxels", "voxels": np.column_stack([rng.integers(0, min(size), (200, 3)),
                                                          rng.integers(1, 256, 200)])}])
        for _ in range(3):
            solids = np.argwhere(expected > 0)[rng.permutation(int((expected > 0).sum()))[:5]]
            step([{"op": "voxels", "voxels": [[int(x), int(y), int(z), 0] for z, y, x in solids]},
                  {"op": "sphere", "center": [float(v) for v in rng.uniform(0, size)], "radius": 3.0, "colour": 0}])
        assert calls == [True, True, True]
        step(adding_batch(rng, size))  # lowered, from the stages the erasing left
        assert calls == [True, True, True]
    finally:
        world.release()


@pytest.mark.parametrize("config", [dict(algorithm="fim"), dict(metric="euclidean", signed=True), dict(signed=True),
                                    dict(focus=Focus((1, 1, 1), (2, 2, 2)))])
def test_worlds_the_lowering_is_not_for_take_their_own_path(gpu, config):
    world = World(gpu, WorldConfig(size=(32, 24, 40), chunk_size=8, max_distance=12, **config))
    try:
        world.apply_edits(parse_edits(adding_batch(np.random.default_rng(), (32, 24, 40))))
        assert world._lowering_boxes() is None
    finally:
        world.release()


def test_regions_under_the_threshold_are_transformed_not_lowered(gpu, monkeypatch):
    """Under ``LOWER_ABOVE_REGION_VOXELS`` of regions the recompute is the transform (no lowering
    launch), and its field equals scipy's; just over it, the same batch is lowered."""
    rng = np.random.default_rng()
    world, size, expected = scattered_world(gpu, rng, 255, 40)
    launched = []
    real_lower = world._lower
    monkeypatch.setattr(world, "_lower", lambda boxes: launched.append(boxes) or real_lower(boxes))
    try:
        batch = adding_batch(rng, size)
        world.apply_edits(parse_edits(batch))
        apply_reference(expected, batch)
        regions = world.dirty_regions()
        volume = sum(r.volume for r in regions)
        monkeypatch.setattr(lower, "LOWER_ABOVE_REGION_VOXELS", volume)
        assert world._lowering_boxes() is None
        world.recompute()
        assert not launched
        assert np.array_equal(distances(world.read_field(), world.config, expected), oracle_distance(expected, 255))
        batch = adding_batch(rng, size)
        world.apply_edits(parse_edits(batch))
        apply_reference(expected, batch)
        monkeypatch.setattr(lower, "LOWER_ABOVE_REGION_VOXELS", sum(r.volume for r in world.dirty_regions()) - 1)
        world.recompute()
        assert len(launched) == 1
        assert np.array_equal(distances(world.read_field(), world.config, expected), oracle_distance(expected, 255))
    finally:
        world.release()


@pytest.mark.parametrize("cap", [3, 17, 255])
def test_adding_solids_lowers_a_euclidean_field_and_its_stages(gpu, cap):
    """The field after adding batches equals scipy's exact Euclidean transform; and the stages the
    world keeps stay current: an erasing batch after them (the incremental transform, which reads
    the stages around its boxes) is exact too."""
    rng = np.random.default_rng()
    size = tuple(int(v) * 8 for v in rng.integers(3, 7, 3))
    world = World(gpu, WorldConfig(size=size, chunk_size=8, max_distance=cap, metric="euclidean"))
    try:
        expected = np.zeros(size[::-1], np.uint8)

        def check():
            got = distances(world.read_field(), world.config, expected)
            want = field_distances(expected, "euclidean", False, cap)
            assert np.allclose(got, want, atol=1e-4), np.abs(got - want).max()

        for i in range(4):
            batch = adding_batch(rng, size)
            world.apply_edits(parse_edits(batch))
            apply_reference(expected, batch)
            assert world._lowering_boxes() is not None
            world.recompute()
            check()
        solids = np.argwhere(expected > 0)[:20]  # (z, y, x)
        erasing = [{"op": "sphere", "center": [float(v) for v in rng.uniform(0, size)], "radius": 6.0, "colour": 0},
                   {"op": "voxels", "voxels": [[int(x), int(y), int(z), 0] for z, y, x in solids]}]
        world.apply_edits(parse_edits(erasing))
        apply_reference(expected, erasing)
        assert world._lowering_boxes() is None
        world.recompute()
        check()
        batch = adding_batch(rng, size)  # and lowering again, from stages the transform rewrote
        world.apply_edits(parse_edits(batch))
        apply_reference(expected, batch)
        world.recompute()
        check()
    finally:
        world.release()


def rows_of_solids(rng, size, count: int, colour_low: int = 1) -> dict:
    """Voxels in a few rows along x, several separated solids each (gaps inside the rows, rows
    left empty between them), and on every face of the world: their chunks' boxes are many, so
    the batch is lowered as one box spanning about the whole world."""
    sx, sy, sz = size
    rows = np.column_stack([rng.integers(0, sy, count), rng.integers(0, sz, count)])
    rows[:2] = [[0, 0], [sy - 1, sz - 1]]
    voxels = []
    for y, z in rows:
        xs = np.unique(rng.integers(0, sx, int(rng.integers(2, 6))))
        voxels += [[int(x), int(y), int(z)] for x in xs]
    voxels += [[0, int(rng.integers(0, sy)), int(rng.integers(0, sz))], [sx - 1, 0, sz - 1]]
    voxels = np.array(voxels)
    return {"op": "voxels", "voxels": np.column_stack([voxels, rng.integers(colour_low, 256, len(voxels))])}


@pytest.mark.parametrize("cap", [3, 30, 255])
@pytest.mark.parametrize("shares", ["as planned", "fewest", "many"])
def test_boxes_spanning_the_world_lower_exactly(gpu, cap, shares, monkeypatch):
    """A box longer than a row's work-group (several scans of lower_x), spanning the world and
    touching its faces, with separated solids in some of its rows and none in others, a sphere
    across most of it; lines of lower_y and lower_z in as few shares as a launch takes, or cut into
    many parts that each start from the rest of the box. Exact after adding, and after erasing and adding
    (the rising box transformed, then lowered), past the 64³ a Euclidean world's box keeps to."""
    if shares == "fewest":
        monkeypatch.setattr(lower, "COLUMN_SHARES", 1)
    elif shares == "many":
        monkeypatch.setattr(lower, "SHARE_DEPTHS", 0)
        monkeypatch.setattr(lower, "SHARE_MIN_VOX", 1)
    rng = np.random.default_rng()
    size = (int(rng.integers(17, 21)) * 8, 48, int(rng.integers(6, 8)) * 8)
    world = World(gpu, WorldConfig(size=size, chunk_size=8, max_distance=cap))
    expected = np.zeros(size[::-1], np.uint8)
    try:
        # a voxel's squared distance from an integer centre is an integer and the radius's square
        # is a quarter off one, so the kernel's float32 test and the reference's float64 one agree
        # on every voxel (a random centre put one on the surface of such a sphere in a few percent
        # of runs)
        sphere = {"op": "sphere", "center": [float(s // 2 + rng.integers(-3, 4)) for s in size],
                  "radius": int(min(size) * 0.45) + 0.5, "colour": int(rng.integers(1, 256))}
        for step in range(3):
            batch = [rows_of_solids(rng, size, 12)] + [[], [sphere], []][step]
            if step == 2:  # erasing too
                solids = np.argwhere(expected > 0)[rng.permutation(int((expected > 0).sum()))[:30]]  # (z, y, x)
                batch.append({"op": "voxels", "voxels": [[int(x), int(y), int(z), 0] for z, y, x in solids]})
            world.apply_edits(parse_edits(batch))
            apply_reference(expected, batch)
            boxes = world._lowering_boxes()
            assert boxes is not None and len(boxes) == 1 and boxes[0].volume > 64 ** 3, step
            assert world.dirty.erased == (step == 2)
            world.recompute()
            field = world.read_field()
            assert np.array_equal(field & 0xFF, expected), step
            assert np.array_equal(distances(field, world.config, expected), oracle_distance(expected, cap)), step
    finally:
        world.release()


def test_boxes_past_the_limit_are_transformed(gpu, monkeypatch):
    """Past ``MAX_BOX_VOXELS`` a Manhattan world's box takes the transform, past
    ``MAX_ERASING_BOX_VOXELS`` where its batch erased; a Euclidean world's past its own
    ``MAX_EUCLIDEAN_BOX_VOXELS``."""
    adding = [{"op": "box", "min": [2, 3, 4], "max": [12, 11, 10], "colour": 5}]  # 10 x 8 x 6
    erasing = [{"op": "box", "min": [2, 3, 4], "max": [12, 11, 10], "colour": 0}]
    for metric, batch, limit in (("manhattan", adding, "MAX_BOX_VOXELS"), ("manhattan", erasing, "MAX_ERASING_BOX_VOXELS"),
                                 ("euclidean", adding, "MAX_EUCLIDEAN_BOX_VOXELS")):
        world = World(gpu, WorldConfig(size=(32, 24, 40), chunk_size=8, max_distance=12, metric=metric))
        try:
            world.recompute()
            world.apply_edits(parse_edits(batch))
            monkeypatch.setattr(lower, limit, 480)
            assert world._lowering_boxes() is not None, limit
            monkeypatch.setattr(lower, limit, 479)
            assert world._lowering_boxes() is None, limit
        finally:
            world.release()
        monkeypatch.undo()
        monkeypatch.setattr(lower, "LOWER_ABOVE_REGION_VOXELS", 0)
