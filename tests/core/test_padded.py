"""Padded chunk borders (the dissertation's §4.2.1, Algorithms 2 and 3): each chunk computed
alone, everything outside it solid. The oracle is scipy's taxicab transform of each chunk inside a
one-voxel solid frame, capped."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import distance_transform_cdt

from sdfserver.edits import BoxEdit, SphereEdit, VoxelsEdit
from sdfserver.gpu import slots
from sdfserver.errors import InvalidInput
from sdfserver.world import World, WorldConfig
from sdfserver.world_config import CHUNK_SIZES

from .conftest import oracle, random_voxels

PADDED_EXACT = ["brute", "fim", "jfa_fim"]
PADDED_JFA = ["jfa", "jfa+1", "jfa+2"]


def padded_oracle(voxels_zyx: np.ndarray, chunk: int, cap: int) -> np.ndarray:
    """Each chunk alone inside a solid frame (one loop over chunks; scipy does the voxels)."""
    out = np.empty(voxels_zyx.shape, np.uint8)
    nz, ny, nx = voxels_zyx.shape
    for z in range(0, nz, chunk):
        for y in range(0, ny, chunk):
            for x in range(0, nx, chunk):
                inside = np.zeros((chunk + 2,) * 3, dtype=bool)  # False: solid, the frame
                inside[1:-1, 1:-1, 1:-1] = voxels_zyx[z:z + chunk, y:y + chunk, x:x + chunk] == 0
                d = distance_transform_cdt(inside, metric="taxicab")[1:-1, 1:-1, 1:-1]
                out[z:z + chunk, y:y + chunk, x:x + chunk] = np.minimum(d, cap)
    return out


def random_edits(rng: np.random.Generator, size) -> list:
    edits = []
    for _ in range(int(rng.integers(1, 4))):
        colour = int(rng.integers(1, 256)) if rng.random() < 0.6 else 0
        kind = rng.integers(0, 3)
        if kind == 0:
            n = int(rng.integers(1, 20))
            edits.append(VoxelsEdit(np.column_stack([rng.integers(0, s, n) for s in size] + [rng.integers(0, 256, n)])))
        elif kind == 1:
            lo = rng.integers(-2, np.array(size))
            edits.append(BoxEdit(tuple(map(int, lo)), tuple(map(int, lo + rng.integers(1, 8, 3))), colour))
        else:
            c = rng.uniform(-2, np.array(size) + 2)
            edits.append(SphereEdit(tuple(map(float, c)), float(rng.uniform(0.5, 5)), colour))
    return edits


# (chunk, world size xyz, cap): several chunks on every axis, caps below and above the chunk.
SHAPES = [(8, (24, 16, 32), 255), (16, (32, 48, 32), 9), (32, (64, 32, 64), 40)]


@pytest.mark.parametrize("algorithm", PADDED_EXACT + PADDED_JFA)
@pytest.mark.parametrize("chunk,size,cap", SHAPES)
def test_padded_equals_per_chunk_oracle(gpu, rng, algorithm, chunk, size, cap):
    if algorithm == "brute" and chunk > 16:
        pytest.skip("brute force scans its chunk per voxel: O(chunk^6)")
    world = World(gpu, WorldConfig(size, chunk, cap, algorithm, borders="padded"))
    try:
        voxels = random_voxels(rng, size[::-1], rng.uniform(0.002, 0.05))
        world.load_voxels(voxels)
        world.recompute()
        field = world.read_field()
        got = (field >> 8).astype(int)
        expected = padded_oracle(voxels, chunk, cap).astype(int)
        assert np.array_equal(field & 0xFF, voxels), "colour byte must be the voxel itself"
        if algorithm in PADDED_EXACT:
            assert np.array_equal(got, expected), f"{(got != expected).sum()} voxels differ from the per-chunk oracle"
            assert (got <= oracle(voxels, cap)).all(), "padding is conservative: never above the truth"
        else:
            error = got - expected
            assert (error >= 0).all(), f"{(error < 0).sum()} voxels below the per-chunk oracle"
            assert (error == 0).mean() >= 0.99 and error.max() <= 2, (error == 0).mean()
    finally:
        world.release()


@pytest.mark.parametrize("algorithm", PADDED_EXACT + ["jfa"])
def test_padded_incremental_touches_only_edited_chunks(gpu, rng, algorithm):
    """Edits that add and remove voxels: the field stays the per-chunk oracle, and a recompute
    rewrites only the chunks the edits touched (no halo growth by the cap)."""
    chunk, size, cap = 8, (32, 24, 16), 255
    world = World(gpu, WorldConfig(size, chunk, cap, algorithm, borders="padded"))
    try:
        voxels = random_voxels(rng, size[::-1], 0.02)
        world.load_voxels(voxels)
        world.recompute()
        for _ in range(5):
            edits = random_edits(rng, size)
            bounds = [b for boxes in world.plan_edits(edits).boxes for b in boxes]
            world.apply_edits(edits)
            result = world.recompute()
            voxels = world.read_voxels()
            got = world.read_distance()
            if algorithm == "jfa":
                assert (got >= padded_oracle(voxels, chunk, cap)).all()
            else:
                assert np.array_equal(got, padded_oracle(voxels, chunk, cap))
            edited = {tuple(c) for b in bounds for c in np.argwhere(
                np.ones(b.chunk_range(chunk).shape_xyz[::-1], bool))[:, ::-1] + b.chunk_range(chunk).lo}
            changed = {tuple(c) for c in result.changed_chunks.tolist()}
            if not bounds:  # every edit fell outside the world
                assert not changed
                continue
            # Touching boxes merge into one region, so a region may hold a chunk between two
            # edits, never one beyond all of them (the cap is 255: any halo would be the world).
            lo = np.min([b.chunk_range(chunk).lo for b in bounds], axis=0)
            hi = np.max([b.chunk_range(chunk).hi for b in bounds], axis=0)
            assert edited <= changed
            assert all((lo <= c).all() and (np.array(c) < hi).all() for c in changed)
    finally:
        world.release()


def test_one_voxel_edit_rewrites_one_chunk(gpu):
    world = World(gpu, WorldConfig((64, 32, 32), 16, 255, "fim", borders="padded"))
    try:
        world.recompute()
        world.apply_edits([VoxelsEdit(np.array([[20, 5, 9, 33]]))])
        result = world.recompute()
        assert result.changed_chunks.tolist() == [[1, 0, 0]]
        d = world.read_distance()
        assert d[9, 5, 20] == 0 and d[9, 5, 16] == 1 and d[9, 5, 15] == 1  # frames on both sides
    finally:
        world.release()


def test_borders_are_validated(gpu):
    with pytest.raises(InvalidInput, match="borders must be one of"):
        WorldConfig((16, 16, 16), 8, borders="seamless").validated()
    with pytest.raises(InvalidInput, match="not available for algorithm 'exact'"):
        WorldConfig((16, 16, 16), 8, borders="padded").validated()
    assert WorldConfig((16, 16, 16), 8).validated().borders == "exact"
    world = World(gpu, WorldConfig((16, 16, 16), 8, 255, "fim", borders="padded"))
    try:
        with pytest.raises(InvalidInput):
            world.reconfigure(algorithm="exact")
        assert world.config.algorithm == "fim" and world.config.borders == "padded"
    finally:
        world.release()


def test_seed_buffers_only_for_worlds_that_flood(gpu, monkeypatch):
    """An exact world keeps its 5 bytes per voxel; flooding worlds add 8, counted before allocation,
    and a reconfigure allocates or releases them."""
    size = (32, 16, 16)
    n = 32 * 16 * 16
    base = World.buffer_bytes(WorldConfig(size, 8).validated())
    assert sum(base) == 5 * n + 16 * 32
    for chunk in CHUNK_SIZES[:2]:
        assert World.buffer_bytes(WorldConfig(size, chunk, algorithm="jfa").validated()) == base + [4 * n, 4 * n]
    from sdfserver.world import Focus
    assert World.buffer_bytes(WorldConfig(size, 8, focus=Focus((1, 1, 1), (1, 1, 1))).validated()) == base + [4 * n] * 2
    monkeypatch.setattr(slots, "POOLED_MAX_VOXELS", 0)  # the world's own buffers, counted alone
    before = gpu.allocated_bytes
    world = World(gpu, WorldConfig(size, 8))
    try:
        assert world.device_bytes == sum(base) and world.buffers.seeds is None
        world.reconfigure(algorithm="jfa_fim", borders="padded")
        assert world.device_bytes == sum(base) + 8 * n == gpu.allocated_bytes - before
        world.reconfigure(algorithm="fim")
        assert world.device_bytes == sum(base) and world.buffers.seeds is None
    finally:
        world.release()
    assert gpu.allocated_bytes == before


def test_borders_survive_the_wire_form():
    """The journal and snapshots store world_config_dict; a config without borders (older logs and
    snapshots) loads as exact."""
    from sdfserver.api.models import CreateWorldBody, PatchWorldBody
    from sdfserver.engine import world_config_dict
    from sdfserver.engine.rebuild import config_from_dict

    config = WorldConfig((16, 16, 16), 8, 9, "jfa+1", borders="padded").validated()
    d = world_config_dict(config)
    assert d["borders"] == "padded" and config_from_dict(d) == config
    del d["borders"]
    assert config_from_dict(d).borders == "exact"
    assert CreateWorldBody.model_validate({"size": [8, 8, 8], "borders": "padded"}).borders == "padded"
    assert CreateWorldBody.model_validate({"size": [8, 8, 8]}).borders == "exact"
    assert PatchWorldBody.model_validate({"borders": "padded"}).borders == "padded"
