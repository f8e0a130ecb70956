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
