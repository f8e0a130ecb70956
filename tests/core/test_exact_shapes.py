"""exact's launch shapes for long lines (algorithms/exact.py, PassShape.long_lanes), forced onto
small worlds by lowering the line length they start at: the field stays scipy's, unsigned and
signed, whole and after edits (regions with their seed shell)."""

from __future__ import annotations

import dataclasses
import weakref

import numpy as np
import pytest
from references import field_distances

from sdfserver.algorithms import ALGORITHMS
from sdfserver.algorithms import exact as exact_module
from sdfserver.edits import BoxEdit, SphereEdit, VoxelsEdit
from sdfserver.world import WorldConfig
from sdfserver.world_factory import make_world

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


def reference(voxels: np.ndarray, cap: int, signed: bool) -> np.ndarray:
    return (np.abs(field_distances(voxels, "manhattan", signed, cap)).astype(np.int64) << 8) | voxels


def edits(rng: np.random.Generator, first: bool) -> list:
    n = int(rng.integers(1, 60))
    xyz = np.stack([rng.integers(0, s, n) for s in SIZE], axis=1)
    colours = rng.integers(1 if first else 0, 256, n)
    lo = [int(rng.integers(0, s - 4)) for s in SIZE]
    return [VoxelsEdit(np.concatenate([xyz, colours[:, None]], axis=1).astype(np.int64)),
            SphereEdit(center=tuple(float(rng.uniform(-2, s + 2)) for s in SIZE),
                       radius=float(rng.uniform(1, 10)), colour=int(rng.integers(0, 3))),
            BoxEdit(min=tuple(lo), max=tuple(v + int(rng.integers(1, 5)) for v in lo), colour=int(rng.integers(0, 2)))]


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
        for step in range(4):
            world.apply_edits(edits(rng, step == 0))
            world.recompute()
            got = world.read_field().astype(np.int64)
            bad = np.argwhere(got != reference(world.read_voxels(), cap, signed))
            assert bad.size == 0, f"step {step}: {len(bad)} voxels differ, first (z, y, x) {bad[:3].tolist()}"
        incremental = world.read_field()
        world.mark_all_dirty()
        world.recompute()
        assert np.array_equal(world.read_field(), incremental)
    finally:
        world.release()
