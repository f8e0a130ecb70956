"""Crews (kernels/include/crew.h, sdfserver/algorithms/one_launch.py): a lone box too large for
one work-group taken by the groups of one launch together, with barriers between them. On the CPU
device the crew is forced (production takes crews on GPUs only); its groups there are the
device's compute units, so two run together, and more than that drop out. Fields equal the
multi-launch algorithms' voxel for voxel and the oracle's where exact, after edits that add and
remove solids."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

from sdfserver.algorithms import one_launch
from sdfserver.algorithms.base import RegionJob
from sdfserver.world import World, WorldConfig

from .conftest import oracle, random_voxels
from .test_one_launch import EXACT, ONE, assert_fim_counts_its_passes, assert_same, inside, run_both, spheres

CREW_ALGORITHMS = ["fim", "jfa", "jfa+1", "jfa_fim"]


@pytest.fixture(autouse=True)
def crews_everywhere(monkeypatch):
    """Every lone box takes a crew, on this device too, with a group for each 64 voxels (as many as
    the device's compute units)."""
    monkeypatch.setattr(one_launch, "takes_crews", lambda gpu: True)
    monkeypatch.setattr(one_launch, "LONE_GROUP_VOXELS", {False: 0, True: 0})
    monkeypatch.setattr(one_launch, "CREW_VOXELS_PER_GROUP", {False: 64, True: 64})


def crew_control(gpu) -> np.ndarray:
    control = np.empty(one_launch.CREW_INTS, np.int32)
    cl.enqueue_copy(gpu.queue, control, one_launch._state(gpu).crew)
    return control


@pytest.mark.parametrize("algorithm", CREW_ALGORITHMS)
@pytest.mark.parametrize("chunk", [8, 16, 32])
@pytest.mark.parametrize("cap", [3, 255])
def test_a_crew_equals_multi_launch(gpu, rng, monkeypatch, algorithm, chunk, cap):
    """A world of one chunk (the dissertation's tables), regenerated, then edited twice."""
    size = (chunk,) * 3
    config = WorldConfig(size, chunk, cap, algorithm)
    world = World(gpu, config)
    try:
        job = RegionJob.halo_region(world.buffers, world.world_box, cap)
        plan = ONE[algorithm].small.chosen(gpu, job)
    finally:
        world.release()
    if plan is None:  # a 32^3 flood does not fit one group's local memory
        assert chunk == 32 and algorithm != "fim"
        return
    assert plan.crew and plan.groups == min(chunk ** 3 // 64, gpu.device.max_compute_units)
    out = run_both(gpu, monkeypatch, config, random_voxels(rng, size[::-1], rng.uniform(0.002, 0.05)),
                   [spheres(rng, size, 2), spheres(rng, size, 3)])
    assert_same(out, cap, oracle if algorithm in EXACT else None)
    launches = [len(result.kernel_ms) for result, _ in out["one"][0]]
    assert launches[0] == 1 and max(launches) == 1, launches  # an edit that changed nothing runs none
    assert not crew_control(gpu).any()


@pytest.mark.parametrize("algorithm", CREW_ALGORITHMS)
def test_seeded_regions_in_crews_equal_multi_launch(gpu, rng, monkeypatch, algorithm):
    """Edits under a small cap in a larger world: regions of a few chunks from their seed shell."""
    size, cap = (48, 40, 32), 3
    out = run_both(gpu, monkeypatch, WorldConfig(size, 8, cap, algorithm), random_voxels(rng, size[::-1], 0.01),
                   [inside(rng, size) for _ in range(4)])
    assert_same(out, cap, oracle if algorithm in EXACT else None)


@pytest.mark.parametrize("algorithm", ["fim", "jfa_fim"])
def test_groups_past_what_runs_at_once_drop_out(gpu, rng, monkeypatch, algorithm):
    """Launched with 16 groups on a device that runs fewer together: those that start late take
    no part, and the field is still the oracle's."""
    monkeypatch.setattr(one_launch, "crew_groups", lambda gpu, voxels, flood: 16)
    size = (16, 16, 16)
    out = run_both(gpu, monkeypatch, WorldConfig(size, 16, 255, algorithm), random_voxels(rng, size[::-1], 0.02),
                   [spheres(rng, size, 3)])
    assert_same(out, 255, oracle)
    assert not crew_control(gpu).any()


def test_a_crew_counts_fim_passes(gpu, monkeypatch):
    """test_one_launch's pass count, in a crew: passes are counted once for the crew."""
    assert_fim_counts_its_passes(gpu, monkeypatch)


def test_crews_are_taken_on_nvidia_gpus_only(gpu, monkeypatch):
    """By default a lone box past LONE_GROUP_VOXELS takes a crew only on an NVIDIA GPU (the device
    fence its barrier needs is PTX's)."""
    monkeypatch.undo()
    world = World(gpu, WorldConfig((32, 32, 32), 32, 255, "fim"))
    try:
        plan = ONE["fim"].small.chosen(gpu, RegionJob.halo_region(world.buffers, world.world_box, 255))
    finally:
        world.release()
    nvidia_gpu = bool(gpu.device.type & cl.device_type.GPU) and "NVIDIA" in gpu.device.platform.name.upper()
    assert (plan is not None and plan.crew) == nvidia_gpu
