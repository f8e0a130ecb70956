"""A sparse world's snapshot (format 2): its brick table and stored bricks, whose size follows the
stored bricks; it restores the same field, and an upload of one is refused."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver.edits import parse_edits
from sdfserver.errors import CorruptData, InvalidInput
from sdfserver.geometry import Box
from sdfserver.sparse.world import SparseWorld
from sdfserver.storage.snapshot import decode_snapshot, decode_upload, encode_snapshot
from sdfserver.world import WorldConfig
from sdfserver.world_config import TerrainSpec

from .conftest import random_batch


def test_a_snapshot_restores_the_same_world(gpu, rng):
    config = WorldConfig((4096, 128, 256), 16, 9, storage="sparse", generate=TerrainSpec(seed=4, base=40,
                                                                                          amplitude=20))
    world = SparseWorld(gpu, config)
    restored = SparseWorld(gpu, config, generate=False)
    try:
        for _ in range(3):
            batch = random_batch(rng, (256, 128, 256), 16)  # the first 256 columns: edits over the terrain
            world.apply_edits(parse_edits(batch))
            world.recompute()
        content, wait = world.copy_voxels_out()
        world.apply_edits(parse_edits([{"op": "box", "min": [0, 0, 0], "max": [64, 128, 64], "colour": 0}]))
        world.recompute()  # after the copy: not in the snapshot
        wait()
        data = encode_snapshot(3, {"size": list(config.size)}, content)
        stored_bytes = world.stored_bricks * 16 ** 3 * 3
        assert len(data) < stored_bytes  # zlib over the stored bricks, not the 2^27-voxel world
        snap = decode_snapshot(data)
        restored.load_voxels(snap.voxels)
        assert restored.stored_bricks == content.used.size
        fresh = SparseWorld(gpu, config)  # the terrain again, and the same three batches
        try:
            rng_box = Box((0, 0, 0), (256, 128, 256))
            far = Box((3800, 0, 0), (4096, 128, 256))
            assert np.array_equal(restored.read_field(far), fresh.read_field(far))
            assert not np.array_equal(restored.read_field(rng_box), world.read_field(rng_box))  # the erase came after
        finally:
            fresh.release()
        restored.apply_edits(parse_edits([{"op": "box", "min": [0, 0, 0], "max": [64, 128, 64], "colour": 0}]))
        restored.recompute()
        assert np.array_equal(restored.read_field(), world.read_field())
    finally:
        world.release()
        restored.release()


def test_sparse_snapshots_are_checked_and_not_uploaded(gpu):
    world = SparseWorld(gpu, WorldConfig((256, 64, 256), 16, 5, storage="sparse"))
    try:
        world.apply_edits(parse_edits([{"op": "sphere", "center": [100, 30, 100], "radius": 9, "colour": 5}]))
        world.recompute()
        content, wait = world.copy_voxels_out()
        wait()
        data = encode_snapshot(1, {"size": [256, 64, 256]}, content)
        with pytest.raises(InvalidInput, match="sparse"):
            decode_upload(data)
        damaged = bytearray(data)
        damaged[-5] ^= 0xFF
        with pytest.raises(CorruptData):
            decode_snapshot(bytes(damaged))
    finally:
        world.release()
