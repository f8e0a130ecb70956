"""Jump flooding's kinds of pass (sdfserver/algorithms/jfa.py): jobs whose seeds are all solids
(a whole world, padded chunks) take the passes that never read a seed's weight, four voxels a
work-item; a seeded region, whose shell weighs its distances, takes the weighted passes. Each
kind must find the same field as the weighted, one-voxel passes."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver.algorithms import ALGORITHMS, jfa
from sdfserver.edits import SphereEdit
from sdfserver.world import World, WorldConfig

from .conftest import oracle, random_voxels

WORLDS = [(8, (48, 32, 40), (0.0005, 0.005)), (16, (64, 48, 32), (0.005, 0.05)), (32, (64, 32, 64), (0.02, 0.2))]


def full_field(world: World) -> np.ndarray:
    world.mark_all_dirty()
    world.recompute()
    return world.read_distance()


@pytest.mark.parametrize("borders", ["exact", "padded"])
@pytest.mark.parametrize("algorithm", ["jfa", "jfa+2"])
@pytest.mark.parametrize("chunk,size,density", WORLDS)
def test_weight_zero_passes_find_the_weighted_field(gpu, rng, monkeypatch, algorithm, borders, chunk, size, density):
    """The same field from the weight-0 passes (four voxels an item, or one), as from the
    passes that read every winning seed's weight; never below scipy's, and on solids 0."""
    monkeypatch.setitem(ALGORITHMS, algorithm, jfa.Jfa(int(algorithm[-1]) if "+" in algorithm else 0,
                                                       one_launch=False))  # a launch a pass, whatever the box
    world = World(gpu, WorldConfig(size, chunk, 255, algorithm, borders=borders))
    try:
        voxels = random_voxels(rng, size[::-1], rng.uniform(*density))
        world.load_voxels(voxels)
        fast = full_field(world)
        monkeypatch.setattr(jfa, "LAYOUT", jfa.PassLayout(vector=False))
        scalar = full_field(world)
        monkeypatch.setattr(jfa, "seeds_weigh_nothing", lambda job: False)
        weighted = full_field(world)
        assert np.array_equal(fast, weighted), f"{(fast != weighted).sum()} voxels differ"
        assert np.array_equal(scalar, weighted), f"{(scalar != weighted).sum()} voxels differ"
        if borders == "exact":
            assert (fast.astype(int) >= oracle(voxels, 255)).all()
        assert (fast[voxels > 0] == 0).all()
    finally:
        world.release()


def test_a_seeded_region_floods_weighted(gpu, rng, monkeypatch):
    """An edit's region is seeded by the field around it: its passes read the shell's weights
    (the weight-0 passes would take the shell for solids and go below the truth), and the
    field stays an upper bound that is exact nearly everywhere."""
    size, cap = (96, 64, 64), 8  # an edit's region grown by the cap is never the whole world
    monkeypatch.setitem(ALGORITHMS, "jfa", jfa.Jfa(one_launch=False))
    world = World(gpu, WorldConfig(size, 16, cap, "jfa"))
    decided = []
    weigh_nothing = jfa.seeds_weigh_nothing
    monkeypatch.setattr(jfa, "seeds_weigh_nothing", lambda job: decided.append(weigh_nothing(job)) or decided[-1])
    try:
        world.load_voxels(random_voxels(rng, size[::-1], 0.003))
        world.recompute()
        assert decided == [True]  # the whole world: its work box is the world, no shell
        for _ in range(3):
            world.apply_edits([SphereEdit(tuple(float(v) for v in rng.uniform(8, 56, 3)), float(rng.uniform(1, 4)),
                                          int(rng.integers(0, 256)))])
            world.recompute()
            error = world.read_distance().astype(int) - oracle(world.read_voxels(), cap).astype(int)
            assert (error >= 0).all(), f"{(error < 0).sum()} voxels below the truth"
            assert (error == 0).mean() >= 0.99 and error.max() <= 2
        assert decided[1:] == [False] * 3
    finally:
        world.release()
