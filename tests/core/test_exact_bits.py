"""exact's x pass as bits (kernels/exact_bits.cl, the y pass's FROM_BITS), which work boxes
without a seed shell take: whole worlds of many shapes and densities equal scipy's field and the
three-pass transform's, halo jobs are exact over their region, and boxes with a seed shell keep
the x pass."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver.algorithms import ALGORITHMS
from sdfserver.algorithms.base import RegionJob
from sdfserver.algorithms.exact import Exact, takes_bits
from sdfserver.geometry import Box
from sdfserver.world import WorldConfig
from sdfserver.world_factory import make_world

from .conftest import oracle, random_voxels

# x-extents that are and are not multiples of a 32-bit word of bits, y-lines of one segment and
# of many, a row of one word and of seven
SHAPES = [(40, 24, 56), (96, 16, 8), (8, 8, 16), (64, 136, 40), (200, 8, 8)]


def regenerate(gpu, voxels: np.ndarray, cap: int, chunk: int, algorithm: Exact | None = None) -> np.ndarray:
    """The distances of a world holding ``voxels`` after a whole-world transform."""
    nz, ny, nx = voxels.shape
    world = make_world(gpu, WorldConfig(size=(nx, ny, nz), chunk_size=chunk, max_distance=cap))
    try:
        world.load_voxels(voxels)
        if algorithm is not None:
            job = RegionJob.seeded_region(world.buffers, world.world_box, cap)
            algorithm.run(gpu, job)
            gpu.queue.finish()
        else:
            world.recompute()
        return world.read_distance()
    finally:
        world.release()


@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("cap", [1, 7, 255])
def test_whole_worlds_match_scipy(gpu, rng, shape, cap):
    exact = ALGORITHMS["exact"]
    launched = [kernel.function_name for kernel, *_ in exact.passes(gpu, shape, bits=True)]
    assert launched == ["solid_bits", "pass_yz", "pass_yz"]  # what a whole world runs
    for density in (0.0, 0.002, 0.05, 0.6):
        voxels = random_voxels(rng, shape[::-1], density)
        got = regenerate(gpu, voxels, cap, 8)
        truth = oracle(voxels, cap)
        bad = np.argwhere(got != truth)
        assert bad.size == 0, f"density {density}: {len(bad)} voxels differ, first (z, y, x) {bad[:3].tolist()}"


def test_bits_equal_the_x_pass(gpu, rng):
    """Rows with solids only far away (beyond the cap and within it), across word borders."""
    shape, cap = (136, 16, 40), 40
    voxels = np.zeros(shape[::-1], dtype=np.uint8)
    for z, y in np.ndindex(shape[2], shape[1]):
        xs = rng.choice(shape[0], size=int(rng.integers(0, 3)), replace=False)
        voxels[z, y, xs] = rng.integers(1, 256, len(xs))
    from_bits = regenerate(gpu, voxels, cap, 8, Exact())
    x_pass = regenerate(gpu, voxels, cap, 8, Exact(from_bits=False))
    assert np.array_equal(from_bits, x_pass)
    assert np.array_equal(from_bits, oracle(voxels, cap))


def test_halo_job_is_exact_over_its_region(gpu, rng):
    size, cap = (64, 48, 56), 9
    voxels = random_voxels(rng, size[::-1], 0.01)
    world = make_world(gpu, WorldConfig(size=size, chunk_size=8, max_distance=cap))
    try:
        world.load_voxels(voxels)
        region = Box((16, 8, 24), (40, 32, 48))
        job = RegionJob.halo_region(world.buffers, region, cap)
        assert takes_bits(job) and job.work_box != job.region
        ALGORITHMS["exact"].run(gpu, job)
        gpu.queue.finish()
        (x0, y0, z0), (x1, y1, z1) = region.lo, region.hi
        got = world.read_distance()[z0:z1, y0:y1, x0:x1]
        assert np.array_equal(got, oracle(voxels, cap)[z0:z1, y0:y1, x0:x1])
    finally:
        world.release()


def test_boxes_with_a_seed_shell_keep_the_x_pass(gpu):
    world = make_world(gpu, WorldConfig(size=(32, 32, 32), chunk_size=8, max_distance=5))
    try:
        job = RegionJob.seeded_region(world.buffers, Box((8, 8, 8), (16, 16, 16)), 5)
        assert not takes_bits(job)
        whole = RegionJob.seeded_region(world.buffers, world.world_box, 5)
        assert takes_bits(whole)
    finally:
        world.release()
