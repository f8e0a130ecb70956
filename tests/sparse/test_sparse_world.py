"""Sparse worlds against dense ones and against scipy: the same batches give the same field on
every stored and implicit brick; uniform bricks are not stored; limits refuse whole batches."""

from __future__ import annotations

import numpy as np
import pytest
from references import apply_edits, oracle_distance

from sdfserver.edits import parse_edits
from sdfserver.errors import DeviceMemoryExceeded, InvalidInput, TooLarge
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext
from sdfserver.sparse.table import AIR, BrickTable, solid_code
from sdfserver.sparse.world import SparseWorld
from sdfserver.world import World, WorldConfig

from .conftest import random_batch


@pytest.mark.parametrize("size,brick,cap", [((128, 32, 96), 8, 6), ((96, 48, 64), 16, 11), ((128, 64, 64), 32, 31)])
def test_sparse_equals_dense_and_scipy_after_random_edits(gpu, rng, size, brick, cap):
    dense = World(gpu, WorldConfig(size, brick, cap))
    sparse = SparseWorld(gpu, WorldConfig(size, brick, cap, storage="sparse"))
    reference = np.zeros(size[::-1], dtype=np.uint8)
    try:
        for _ in range(6):
            batch = random_batch(rng, size, brick)
            apply_edits(reference, batch)
            dense.apply_edits(parse_edits(batch))
            sparse.apply_edits(parse_edits(batch))
            dense.recompute()
            result = sparse.recompute()
            field = sparse.read_field()
            assert np.array_equal(field, dense.read_field())
            assert np.array_equal(field & 0xFF, reference)
            assert np.array_equal(field >> 8, oracle_distance(reference, cap))
            assert result.regions == dense.last_recompute.regions
            assert sparse.version == dense.version and sparse.field_version == sparse.version
    finally:
        dense.release()
        sparse.release()


def test_uniform_bricks_are_not_stored(gpu):
    """All air at the cap and all solid of one colour take no pool slot; a brick that stops being
    uniform gets one, and erasing everything gives every slot back."""
    world = SparseWorld(gpu, WorldConfig((128, 64, 128), 16, 4, storage="sparse"))
    try:
        assert world.stored_bricks == 0
        world.apply_edits(parse_edits([{"op": "box", "min": [32, 16, 32], "max": [96, 48, 96], "colour": 7}]))
        world.recompute()
        inner = world.table.get(Box((3, 2, 3), (5, 3, 5)))  # bricks inside the box: solid, not stored
        assert (inner == solid_code(7)).all()
        # The box's 4x2x4 bricks: the inner 2x1x2... shell bricks hold air within the cap or other
        # colour; count what is mixed against a host classification of the same field.
        field = world.read_field()
        blocks = field.reshape(8, 16, 4, 16, 8, 16).transpose(0, 2, 4, 1, 3, 5).reshape(8, 4, 8, -1)
        uniform = (blocks == blocks[..., :1]).all(axis=-1)
        air_at_cap = uniform & (blocks[..., 0] == 4 << 8)
        solid = uniform & ((blocks[..., 0] & 0xFF) != 0)
        assert world.stored_bricks == int((~(air_at_cap | solid)).sum()) > 0
        codes = world.table.get(Box((0, 0, 0), (8, 4, 8)))
        assert ((codes >= 0) == ~(air_at_cap | solid)).all()
        assert (codes[air_at_cap] == AIR).all()
        world.apply_edits(parse_edits([{"op": "box", "min": [0, 0, 0], "max": [128, 64, 128], "colour": 0}]))
        world.recompute()
        assert world.stored_bricks == 0
        assert not world.table.blocks
        assert (world.read_field() == 4 << 8).all()
    finally:
        world.release()


def test_brick_table_two_levels_keep_only_what_is_not_air():
    table = BrickTable((2048, 128, 2048))
    codes = np.full((3, 2, 40), AIR, dtype=np.int32)
    codes[1, 1, 17] = 5
    codes[2, 0, 39] = solid_code(200)
    box = Box((10, 15, 30), (50, 17, 33))  # crosses blocks on every axis
    table.set(box, codes)
    assert np.array_equal(table.get(box), codes)
    assert len(table.blocks) == 2
    assert table.get(Box((27, 16, 31), (28, 17, 32)))[0, 0, 0] == 5
    table.set(box, np.full_like(codes, AIR))
    assert not table.blocks


def test_sides_past_dense_limits_are_sparse_only():
    with pytest.raises(InvalidInput, match="sparse"):
        WorldConfig((4096, 256, 256), 32).validated()
    WorldConfig((65536, 4096, 65536), 32, storage="sparse").validated()
    for size in ((65536, 8192, 32), (131072, 32, 32)):
        with pytest.raises(InvalidInput):
            WorldConfig(size, 32, storage="sparse").validated()
    with pytest.raises(InvalidInput):
        WorldConfig((64, 64, 64), 16, storage="paged").validated()


def test_creation_that_cannot_fit_is_refused_before_allocating(gpu):
    small = GpuContext(gpu.device, memory_budget_bytes=1 << 20)
    with pytest.raises(DeviceMemoryExceeded):
        SparseWorld(small, WorldConfig((4096, 256, 4096), 32, 255, storage="sparse"))
    assert small.allocated_bytes == 0


def test_pool_exhaustion_refuses_the_whole_batch_and_changes_nothing(gpu):
    """A batch whose worst case does not fit the budget is refused (507) before anything is
    applied; the world's field, version and bricks are as before, and it takes smaller batches."""
    budget = 3 << 20
    small = GpuContext(gpu.device, memory_budget_bytes=budget)
    world = SparseWorld(small, WorldConfig((1024, 32, 1024), 16, 3, storage="sparse"))
    try:
        world.apply_edits(parse_edits([{"op": "sphere", "center": [20, 16, 20], "radius": 5, "colour": 9}]))
        world.recompute()
        before = world.read_field(Box((0, 0, 0), (64, 32, 64)))
        stored, version, allocated = world.stored_bricks, world.version, small.allocated_bytes
        huge = [{"op": "sphere", "center": [x, 16, z], "radius": 6, "colour": 3}
                for x in range(100, 1000, 40) for z in range(100, 1000, 40)]
        with pytest.raises(DeviceMemoryExceeded):
            world.apply_edits(parse_edits(huge))
        assert (world.version, world.stored_bricks) == (version, stored)
        assert not world.dirty and not world.reserved and small.allocated_bytes == allocated
        world.recompute()
        assert np.array_equal(world.read_field(Box((0, 0, 0), (64, 32, 64))), before)
        world.apply_edits(parse_edits([{"op": "sphere", "center": [500, 16, 500], "radius": 4, "colour": 1}]))
        world.recompute()
        assert world.read_field(Box((500, 16, 500), (501, 17, 501)))[0, 0, 0] == 1
        assert small.allocated_bytes <= budget
    finally:
        world.release()


def test_a_region_wider_than_one_scratch_box_is_refused(gpu):
    world = SparseWorld(gpu, WorldConfig((8192, 32, 64), 32, 8, storage="sparse"))
    try:
        with pytest.raises(TooLarge):
            world.apply_edits(parse_edits([{"op": "box", "min": [0, 0, 0], "max": [4000, 4, 4], "colour": 1}]))
        assert world.version == 0 and not world.dirty
    finally:
        world.release()


def test_a_terrain_too_large_to_store_is_refused_early_and_holds_nothing(gpu):
    """A 65536 x 256 x 65536 terrain's surface band needs far more than the budget: refused (507)
    after bounding a strip of its columns, not all 2^32 of them, with nothing left allocated."""
    import time

    from sdfserver.world_config import TerrainSpec

    small = GpuContext(gpu.device, memory_budget_bytes=256 << 20)
    started = time.perf_counter()
    with pytest.raises(DeviceMemoryExceeded):
        SparseWorld(small, WorldConfig((65536, 256, 65536), 32, 15, storage="sparse", generate=TerrainSpec(seed=2)))
    assert time.perf_counter() - started < 60
    assert small.allocated_bytes == 0


def test_bricks_across_pool_segments(gpu, rng):
    """Pools of several segments (here 20 bricks each): the field still equals the dense world's,
    and a snapshot taken across segments loads into another world."""
    from sdfserver.storage.snapshot import decode_snapshot, encode_snapshot

    size, brick, cap = (96, 48, 64), 16, 11
    dense = World(gpu, WorldConfig(size, brick, cap))
    sparse = SparseWorld(gpu, WorldConfig(size, brick, cap, storage="sparse"), segment_bricks=20)
    other = SparseWorld(gpu, WorldConfig(size, brick, cap, storage="sparse"), segment_bricks=20)
    try:
        for _ in range(5):
            batch = random_batch(rng, size, brick)
            for world in (dense, sparse):
                world.apply_edits(parse_edits(batch))
                world.recompute()
            assert np.array_equal(sparse.read_field(), dense.read_field())
        sparse.apply_edits(parse_edits([{"op": "box", "min": [0, 0, 0], "max": [96, 24, 64], "colour": 0x33},
                                        {"op": "sphere", "center": [48, 30, 32], "radius": 14, "colour": 0}]))
        dense.apply_edits(parse_edits([{"op": "box", "min": [0, 0, 0], "max": [96, 24, 64], "colour": 0x33},
                                       {"op": "sphere", "center": [48, 30, 32], "radius": 14, "colour": 0}]))
        sparse.recompute()
        dense.recompute()
        assert np.array_equal(sparse.read_field(), dense.read_field())
        assert len(sparse.pool.segments) >= 2
        content, wait = sparse.copy_voxels_out()
        wait()
        other.load_voxels(decode_snapshot(encode_snapshot(1, {"size": list(size)}, content)).voxels)
        assert len(other.pool.segments) >= 2
        assert np.array_equal(other.read_field(), dense.read_field())
    finally:
        for world in (dense, sparse, other):
            world.release()
