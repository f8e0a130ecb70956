"""conservative: never above scipy's capped taxicab distance, 0 exactly on solids, >= 1 on air."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver.algorithms import ALGORITHMS
from sdfserver.algorithms.conservative import Conservative
from sdfserver.edits import parse_edits
from sdfserver.world import Focus, World, WorldConfig

from .conftest import oracle, random_voxels


def check_lower_bound(world: World, voxels: np.ndarray) -> np.ndarray:
    """Assert the field is a safe lower bound of the truth; returns (field distance, oracle)."""
    field = world.read_field()
    got, colour = (field >> 8).astype(np.int32), field & 0xFF
    truth = oracle(voxels, world.config.max_distance).astype(np.int32)
    above = np.argwhere(got > truth)
    assert len(above) == 0, f"{len(above)} voxels above the truth, first (z, y, x) {above[:3].tolist()}"
    assert np.array_equal(got == 0, voxels != 0), "distance 0 must mean exactly the solids"
    assert np.array_equal(colour, voxels), "solids carry their colour, air 0"
    return got, truth


@pytest.fixture(params=[8, 4], ids=["brick8", "brick4"])
def brick(request, monkeypatch):
    monkeypatch.setitem(ALGORITHMS, "conservative", Conservative(request.param))
    return request.param


@pytest.mark.parametrize("density", [0.001, 0.02, 0.3])
@pytest.mark.parametrize("chunk,size,cap", [(8, (40, 24, 32), 255), (16, (32, 48, 16), 9)])
def test_full_recompute_never_above_oracle(gpu, rng, brick, density, chunk, size, cap):
    voxels = random_voxels(rng, size[::-1], density)
    world = World(gpu, WorldConfig(size, chunk, cap, "conservative"))
    world.load_voxels(voxels)
    world.recompute()
    got, truth = check_lower_bound(world, voxels)
    # A solid's brick box reaches at most brick - 1 past it on each axis: a full recompute (no
    # seed shell) is within 3 (brick - 1) of the truth everywhere.
    assert np.all(truth - got <= 3 * (brick - 1))
    world.release()


def test_bound_is_useful_on_a_scene(gpu, brick):
    """Far from solids the bound is the distance to the nearest solid brick's box: on a floor
    with a few shapes it stays close to the truth (a field of 1s would pass the other tests)."""
    size = 64
    z, y, x = np.mgrid[:size, :size, :size]
    voxels = np.zeros((size, size, size), np.uint8)
    voxels[y < 2] = 0x6D
    voxels[(x - 40) ** 2 + (y - 20) ** 2 + (z - 24) ** 2 <= 64] = 0xE0
    voxels[(x == 12) & (z == 50) & (y < 40)] = 0xFC
    world = World(gpu, WorldConfig((size,) * 3, 16, 255, "conservative"))
    world.load_voxels(voxels)
    world.recompute()
    got, truth = check_lower_bound(world, voxels)
    air = voxels == 0
    assert got[air].mean() >= 0.7 * truth[air].mean()
    # Straight above the floor, far from the shapes, the bound is the distance to the floor's
    # bricks: short of the truth by the floor's brick, less the floor's thickness.
    assert np.all(truth[:8, 10:16, 56:] - got[:8, 10:16, 56:] == brick - 2)
    world.release()


def test_incremental_edits_never_above_oracle(gpu, rng, brick):
    # A small cap keeps regions small, so solids beyond them reach R only through the seed shell.
    size, cap = (64, 32, 40), int(rng.integers(3, 9))
    voxels = random_voxels(rng, size[::-1], 0.01)
    world = World(gpu, WorldConfig(size, 8, cap, "conservative"))
    world.load_voxels(voxels)
    world.recompute()
    for _ in range(6):
        ops = []
        for _ in range(3):
            colour = int(rng.integers(1, 256)) if rng.random() < 0.6 else 0  # add and remove
            if rng.random() < 0.5:
                lo = rng.integers(0, size)
                hi = np.minimum(lo + rng.integers(1, 12, 3), size)
                ops.append({"op": "box", "min": lo.tolist(), "max": hi.tolist(), "colour": colour})
                voxels[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]] = colour
            else:
                c, r = rng.integers(0, size), int(rng.integers(1, 7)) + 0.5
                ops.append({"op": "sphere", "center": c.tolist(), "radius": r, "colour": colour})
                zz, yy, xx = np.ogrid[:size[2], :size[1], :size[0]]
                voxels[(xx - c[0]) ** 2 + (yy - c[1]) ** 2 + (zz - c[2]) ** 2 <= r * r] = colour
        world.apply_edits(parse_edits(ops))
        world.recompute()
        check_lower_bound(world, voxels)
    world.release()


def test_as_lod_outside_a_focus(gpu, rng):
    """exact inside the focus, conservative around it: the whole field is a lower bound, exact in
    the focus, and below the truth somewhere outside (the focus is not ignored)."""
    size, chunk, cap = (48, 48, 48), 8, 255
    world = World(gpu, WorldConfig(size, chunk, cap, "exact", focus=Focus((3, 3, 3), (2, 2, 2)),
                                   lod_algorithm="conservative"))
    voxels = random_voxels(rng, size[::-1], 0.003)
    world.load_voxels(voxels)
    result = world.recompute()
    assert set(result.algorithms) == {"exact", "conservative"}
    inside = (slice(16, 32),) * 3
    for _ in range(3):
        got, truth = check_lower_bound(world, voxels)
        assert np.array_equal(got[inside], truth[inside])
        outside = np.ones(voxels.shape, bool)
        outside[inside] = False
        assert (got[outside] < truth[outside]).any()
        c = rng.integers(8, 40, 3)
        world.apply_edits(parse_edits([{"op": "sphere", "center": c.tolist(), "radius": 4.5, "colour": 0},
                                       {"op": "box", "min": (c - 2).tolist(), "max": (c + 1).tolist(),
                                        "colour": 7}]))
        zz, yy, xx = np.ogrid[:48, :48, :48]
        voxels[(xx - c[0]) ** 2 + (yy - c[1]) ** 2 + (zz - c[2]) ** 2 <= 4.5 ** 2] = 0
        voxels[c[2] - 2:c[2] + 1, c[1] - 2:c[1] + 1, c[0] - 2:c[0] + 1] = 7
        world.recompute()
    world.release()


def test_bad_brick_size():
    with pytest.raises(ValueError, match="brick_vox"):
        Conservative(16)
