"""Euclidean and signed fields against scipy, dense and sparse, full and after random edits that
add and remove voxels across chunk borders and at the world's faces (docs/algorithms.md,
"Metrics and signs")."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver.edits import BoxEdit, VoxelsEdit
from sdfserver.errors import InvalidInput
from sdfserver.field_values import distances
from sdfserver.world import WorldConfig
from sdfserver.world_factory import make_world

from .conftest import edit_and_compare, random_batch, stored_field

COMBINATIONS = [(storage, metric, signed) for storage in ("dense", "sparse") for metric in ("manhattan", "euclidean")
                for signed in (False, True)]


@pytest.mark.parametrize("storage,metric,signed", COMBINATIONS)
@pytest.mark.parametrize("cap", [4, 255])
def test_incremental_matches_full_and_scipy(gpu, rng, storage, metric, signed, cap):
    size = (40, 24, 32)  # chunks of 8: borders everywhere
    world = make_world(gpu, WorldConfig(size=size, chunk_size=8, max_distance=cap, metric=metric, signed=signed,
                                        storage=storage))
    try:  # in a dense world the full transform gives the same field too
        edit_and_compare(world, rng, size, 5, cap, metric, signed, full=storage == "dense")
    finally:
        world.release()


@pytest.mark.parametrize("metric", ["manhattan", "euclidean"])
def test_sparse_implicit_bricks_read_as_their_values(gpu, metric):
    """A solid block deeper than the cap leaves implicit solid bricks, and open space implicit air
    bricks: both read back as the values scipy gives (the signed inside at minus the cap)."""
    cap = 3
    world = make_world(gpu, WorldConfig(size=(64, 64, 64), chunk_size=8, max_distance=cap, metric=metric,
                                        signed=True, storage="sparse"))
    try:
        world.apply_edits([BoxEdit(min=(8, 8, 8), max=(48, 40, 56), colour=7)])
        world.recompute()
        stored = world.stored_bricks
        assert 0 < stored < (64 // 8) ** 3 - 8  # some solid bricks and most air bricks are implicit
        got = world.read_field().astype(np.int64)
        assert np.array_equal(got, stored_field(world.read_voxels(), cap, metric, True))
        d = world.read_distance()
        assert d.min() == -cap and d.max() == cap
    finally:
        world.release()


def test_read_distance_types_and_signs(gpu):
    voxels = np.zeros((8, 8, 16), dtype=np.uint8)
    voxels[4, 4, 4:12] = 9
    for metric, signed, dtype in (("manhattan", False, np.uint8), ("manhattan", True, np.int16),
                                  ("euclidean", False, np.float32), ("euclidean", True, np.float32)):
        world = make_world(gpu, WorldConfig(size=(16, 8, 8), chunk_size=8, metric=metric, signed=signed))
        try:
            world.load_voxels(voxels)
            world.recompute()
            d = world.read_distance()
            assert d.dtype == dtype
            assert d[4, 4, 8] == (-1 if signed else 0)  # a solid one voxel from air
            assert d[4, 5, 5] == 1 and d[4, 4, 2] == 2
            assert d[6, 6, 3] == pytest.approx(5.0 if metric == "manhattan" else np.sqrt(1 + 4 + 4))
            assert np.array_equal(distances(world.read_field(), world.config, world.read_voxels()), d)
        finally:
            world.release()


def test_patch_switches_metric_and_sign(gpu, rng):
    size = (32, 16, 24)
    world = make_world(gpu, WorldConfig(size=size, chunk_size=8, max_distance=20))
    try:
        world.apply_edits(random_batch(rng, size, True))
        world.recompute()
        for metric, signed in (("euclidean", False), ("euclidean", True), ("manhattan", True), ("manhattan", False)):
            world.reconfigure(metric=metric, signed=signed)
            world.recompute()
            assert np.array_equal(world.read_field().astype(np.int64),
                                  stored_field(world.read_voxels(), 20, metric, signed))
            world.apply_edits(random_batch(rng, size, False))
            world.recompute()
            assert np.array_equal(world.read_field().astype(np.int64),
                                  stored_field(world.read_voxels(), 20, metric, signed))
        before = world.version, world.field_version
        world.reconfigure(voxel_size=0.25, origin=(1.0, -2.0, 3.5))
        assert not world.dirty and (world.version, world.field_version) == before  # nothing to recompute
    finally:
        world.release()


@pytest.mark.parametrize("changes,named", [
    ({"metric": "chebyshev"}, "metric"), ({"signed": "yes"}, "signed"), ({"voxel_size": 0.0}, "voxel_size"),
    ({"voxel_size": float("nan")}, "voxel_size"), ({"voxel_size": float("inf")}, "voxel_size"),
    ({"origin": (0.0, float("nan"), 0.0)}, "origin"), ({"origin": (1.0, 2.0)}, "origin"),
    ({"palette": [(1, 2, 3)] * 254}, "palette"), ({"palette": [(1, 2, 300)] * 255}, "palette"),
    ({"palette": [(1, 2, 3.5)] * 255}, "palette"),
    ({"metric": "euclidean", "algorithm": "jfa"}, "exact"), ({"signed": True, "algorithm": "fim"}, "exact"),
])
def test_bad_field_options_are_refused_by_name(changes, named):
    with pytest.raises(InvalidInput, match=named):
        WorldConfig(size=(16, 16, 16), chunk_size=8, **changes).validated()


@pytest.mark.parametrize("storage", ["dense", "sparse"])
@pytest.mark.parametrize("metric", ["manhattan", "euclidean"])
def test_signed_edit_deep_inside_a_solid(gpu, storage, metric):
    """An edit deep inside a solid rewrites a region whose every voxel is solid: their distances
    to air reach the cap, bounded by the world's faces only (a sparse world computes the region in
    a scratch box, whose faces are not the world's)."""
    cap = 5
    world = make_world(gpu, WorldConfig(size=(64, 48, 64), chunk_size=8, max_distance=cap, metric=metric,
                                        signed=True, storage=storage))
    try:
        world.apply_edits([BoxEdit(min=(0, 0, 0), max=(64, 40, 64), colour=3)])
        world.recompute()
        world.apply_edits([VoxelsEdit(np.array([[32, 20, 32, 9], [33, 20, 32, 0]]))])
        world.recompute()
        assert np.array_equal(world.read_field().astype(np.int64), stored_field(world.read_voxels(), cap, metric, True))
    finally:
        world.release()


@pytest.mark.parametrize("storage", ["dense", "sparse"])
@pytest.mark.parametrize("metric", ["manhattan", "euclidean"])
def test_signed_edit_above_a_floor(gpu, storage, metric):
    """A small edit above a solid floor: the region's seed shell crosses the floor's surface,
    where the field holds the solids' inside distances and the air's outside ones."""
    cap = 3
    world = make_world(gpu, WorldConfig(size=(64, 32, 64), chunk_size=8, max_distance=cap, metric=metric,
                                        signed=True, storage=storage))
    try:
        world.apply_edits([BoxEdit(min=(0, 0, 0), max=(64, 16, 64), colour=3)])
        world.recompute()
        for voxel in ([32, 20, 32, 9], [32, 20, 32, 0], [30, 15, 33, 0], [30, 15, 33, 4]):
            world.apply_edits([VoxelsEdit(np.array([voxel]))])
            world.recompute()
            assert world.last_recompute.regions != [world.world_box]
            assert np.array_equal(world.read_field().astype(np.int64),
                                  stored_field(world.read_voxels(), cap, metric, True)), voxel
    finally:
        world.release()


@pytest.mark.parametrize("cap", [3, 20])
def test_sparse_switches_metric_and_sign(gpu, rng, cap):
    """A sparse world's PATCH of metric or sign recomputes every brick a solid can reach, with
    the edits still pending written first; the field then equals scipy's, and so after more edits."""
    size = (64, 32, 48)
    world = make_world(gpu, WorldConfig(size=size, chunk_size=8, max_distance=cap, storage="sparse"))
    try:
        world.apply_edits([BoxEdit(min=(8, 0, 8), max=(40, 12, 40), colour=3)])
        world.recompute()
        for metric, signed in (("euclidean", False), ("euclidean", True), ("manhattan", True), ("manhattan", False)):
            world.apply_edits(random_batch(rng, size, False))  # pending when the switch comes
            world.reconfigure(metric=metric, signed=signed)
            result = world.recompute()
            assert result.regions and world.field_version == world.version
            assert np.array_equal(world.read_field().astype(np.int64),
                                  stored_field(world.read_voxels(), cap, metric, signed)), (metric, signed)
            world.apply_edits(random_batch(rng, size, False))
            world.recompute()
            assert np.array_equal(world.read_field().astype(np.int64),
                                  stored_field(world.read_voxels(), cap, metric, signed)), (metric, signed)
        with pytest.raises(InvalidInput, match="cannot change"):
            world.reconfigure(max_distance=5)
    finally:
        world.release()
