"""exact's launch shapes for long lines (algorithms/exact.py, PassShape.long_lanes), forced onto
small worlds by lowering the line length they start at: the field stays scipy's, unsigned and
signed, whole and after edits (regions with their seed shell)."""

from __future__ import annotations

import dataclasses
import weakref

import pytest

from sdfserver.algorithms import ALGORITHMS
from sdfserver.algorithms import exact as exact_module
from sdfserver.world import WorldConfig
from sdfserver.world_factory import make_world

from .conftest import edit_and_compare

SIZE = (40, 24, 32)  # chunks of 8: regions with seed shells on every side


@pytest.fixture
def long_shapes(monkeypatch):
    """Every pass with a long-line shape takes it from lines of 8 voxels; the registry's exact
    forgets the shapes it memoized."""
    shapes = {axis: dataclasses.replace(shape, long_line=8) if shape.long_lanes else shape
              for axis, shape in exact_module.PASS_SHAPES.items()}
    assert any(shape.long_lanes for shape in shapes.values())
    monkeypatch.setattr(exact_module, "PASS_SHAPES", shapes)
    monkeypatch.setattr(ALGORITHMS["exact"], "_passes", weakref.WeakKeyDictionary())
    return shapes


@pytest.mark.parametrize("signed", [False, True])
@pytest.mark.parametrize("cap", [5, 255])
def test_long_line_shapes_match_scipy(gpu, rng, long_shapes, signed, cap):
    exact = ALGORITHMS["exact"]
    for axis, shape in long_shapes.items():  # the forced shape is the one launched
        if shape.long_lanes:
            _, _, _, local = exact.launch_shape(gpu, axis, SIZE[axis], *SIZE)
            assert local[0] == shape.long_lanes
    world = make_world(gpu, WorldConfig(size=SIZE, chunk_size=8, max_distance=cap, signed=signed))
    try:
        edit_and_compare(world, rng, SIZE, 4, cap, "manhattan", signed)
    finally:
        world.release()


# Segment counts that are not powers of two: x, y and z lines of 552, 600 and 1064 voxels run in
# 40, 40 and 72 segments of 16, the z pass's at 8 x-lanes (lines of 1024 and more); the others
# (8 and 16) in 8 segments of 4 (y, z) or 8 (x)
LONG_SIZES = [(552, 16, 8), (16, 600, 8), (8, 16, 1064)]


@pytest.mark.parametrize("size", LONG_SIZES)
@pytest.mark.parametrize("signed", [False, True])
def test_lines_of_any_segment_count_match_scipy(gpu, rng, size, signed):
    cap = 255
    world = make_world(gpu, WorldConfig(size=size, chunk_size=8, max_distance=cap, signed=signed))
    try:
        edit_and_compare(world, rng, size, 3, cap, "manhattan", signed)
    finally:
        world.release()


def test_segment_counts_cover_every_line_with_few_idle():
    """Every line length a world can have is covered by its segments within the work-group limit,
    with fewer than COUNT_STEP segments idle."""
    for axis in exact_module.PASS_SHAPES:
        for line in range(8, 2049, 8):
            seg, count, lanes = exact_module.pass_variant(axis, line)
            assert seg * count >= line and count * lanes <= exact_module.MAX_GROUP, (axis, line)
            assert seg * (count - exact_module.COUNT_STEP) < line, (axis, line, seg, count)


def test_exact_work_boxes_take_whole_field_sectors(gpu):
    """exact's work boxes start and end on multiples of 16 voxels along x (Exact.x_align), the
    other algorithms' on multiples of 8."""
    from sdfserver.algorithms.region_jobs import region_jobs
    from sdfserver.geometry import Box

    region = Box((48, 0, 8), (56, 16, 16))
    for algorithm, x_bounds in (("exact", (32, 64)), ("fim", (40, 64))):
        world = make_world(gpu, WorldConfig(size=(96, 16, 24), chunk_size=8, max_distance=9, algorithm=algorithm))
        try:
            (_, job), = region_jobs(world.config, world.buffers, world.world_box, region)
            assert (job.work_box.lo[0], job.work_box.hi[0]) == x_bounds, algorithm
        finally:
            world.release()
