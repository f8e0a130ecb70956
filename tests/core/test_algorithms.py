"""Every exact algorithm equals scipy's taxicab transform, capped, across chunk borders."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver.algorithms import ALGORITHMS
from sdfserver.algorithms.base import AlgorithmRun, init_work, pack_region
from sdfserver.edits import BoxEdit, SphereEdit, VoxelsEdit
from sdfserver.world import Focus, World, WorldConfig
from sdfserver.world_config import CHUNK_SIZES

from .conftest import oracle, random_voxels

EXACT = ["exact", "brute", "fim", "jfa_fim"]
JFA = ["jfa", "jfa+1", "jfa+2"]


def check_field(world: World, voxels: np.ndarray) -> None:
    cap = world.config.max_distance
    field = world.read_field()
    expected = oracle(voxels, cap)
    distance = (field >> 8).astype(np.uint8)
    mismatch = np.argwhere(distance != expected)
    assert mismatch.size == 0, (
        f"{len(mismatch)} voxels differ; first at zyx {mismatch[0].tolist()}: "
        f"got {distance[tuple(mismatch[0])]}, expected {expected[tuple(mismatch[0])]}"
    )
    assert np.array_equal(field & 0xFF, voxels), "colour byte must be the voxel itself"


# (algorithm, chunk size, world size xyz, cap): brute only where O(n^6) stays small.
CASES = [
    ("exact", 8, (24, 40, 16), 255),
    ("exact", 16, (48, 16, 32), 7),
    ("exact", 32, (64, 32, 96), 40),
    ("exact", 64, (64, 128, 64), 255),
    ("exact", 128, (128, 128, 128), 200),
    ("fim", 8, (24, 16, 32), 255),
    ("fim", 16, (32, 32, 48), 12),
    ("fim", 32, (64, 32, 32), 100),
    ("jfa_fim", 8, (16, 24, 40), 255),
    ("jfa_fim", 16, (48, 32, 16), 9),
    ("jfa_fim", 32, (32, 64, 32), 60),
    ("brute", 8, (16, 24, 16), 255),
    ("brute", 16, (32, 16, 16), 6),
]


@pytest.mark.parametrize("algorithm,chunk,size,cap", CASES)
def test_full_recompute_matches_oracle(gpu, rng, algorithm, chunk, size, cap):
    world = World(gpu, WorldConfig(size, chunk, cap, algorithm))
    try:
        voxels = random_voxels(rng, size[::-1], rng.uniform(0.0005, 0.03))
        world.load_voxels(voxels)
        world.recompute()
        check_field(world, voxels)
    finally:
        world.release()


@pytest.mark.parametrize("algorithm", EXACT)
def test_solids_on_chunk_borders(gpu, rng, algorithm):
    """Solids on both sides of every chunk face; distances must cross borders exactly."""
    chunk, size, cap = 8, (32, 24, 16), 255
    voxels = np.zeros(size[::-1], np.uint8)
    for axis in range(3):
        n = voxels.shape[axis]
        planes = np.arange(chunk - 1, n - 1, chunk)
        for p in rng.choice(np.concatenate([planes, planes + 1]), 3):
            coords = [rng.integers(0, s, 4) for s in voxels.shape]
            coords[axis] = np.full(4, p)
            voxels[tuple(coords)] = rng.integers(1, 256, 4)
    world = World(gpu, WorldConfig(size, chunk, cap, algorithm))
    try:
        world.load_voxels(voxels)
        world.recompute()
        check_field(world, voxels)
    finally:
        world.release()


def test_empty_world_is_all_cap(gpu):
    world = World(gpu, WorldConfig((16, 16, 16), 8, 37))
    try:
        world.apply_edits([BoxEdit((0, 0, 0), (0, 0, 0), 5)])  # touches nothing
        world.recompute()
        assert (world.read_distance() == 37).all()
    finally:
        world.release()


def test_single_solid_gives_diamond(gpu):
    world = World(gpu, WorldConfig((32, 32, 32), 16, 255))
    try:
        world.apply_edits([VoxelsEdit(np.array([[5, 20, 30, 77]]))])
        world.recompute()
        z, y, x = np.indices((32, 32, 32))
        expected = np.abs(x - 5) + np.abs(y - 20) + np.abs(z - 30)
        assert np.array_equal(world.read_distance(), expected)
        assert world.read_field()[30, 20, 5] == 77
    finally:
        world.release()


# Small worlds of two or three chunks a side at every chunk size; brute and fim only where they
# stay quick on a CPU device.
INCREMENTAL_SIZES = {8: (32, 24, 40), 16: (48, 32, 32), 32: (64, 32, 64), 64: (128, 64, 64), 128: (128, 128, 256)}
INCREMENTAL = ([("exact", 255, c) for c in CHUNK_SIZES] + [("exact", 10, c) for c in CHUNK_SIZES]
               + [("fim", 20, c) for c in (8, 16, 32)] + [("jfa_fim", 255, c) for c in (8, 16, 32, 64)]
               + [("brute", 5, c) for c in (8, 16)])


def test_incremental_cases_cover_every_chunk_size():
    assert set(CHUNK_SIZES) <= {c for _, _, c in INCREMENTAL} == set(INCREMENTAL_SIZES)


@pytest.mark.parametrize("algorithm,cap,chunk", INCREMENTAL)
def test_incremental_equals_full_equals_oracle(gpu, rng, algorithm, cap, chunk):
    """Edit sequences that add and remove voxels; each incremental field equals a fresh full one."""
    size = INCREMENTAL_SIZES[chunk] if algorithm != "brute" else (24, 16, 16) if chunk == 8 else (32, 32, 16)
    world = World(gpu, WorldConfig(size, chunk, cap, algorithm))
    try:
        previous = random_voxels(rng, size[::-1], 0.01)
        world.load_voxels(previous)
        world.recompute()
        for step in range(6):
            edits = []
            for _ in range(rng.integers(1, 4)):
                kind = rng.integers(0, 3)
                colour = int(rng.integers(0, 256)) if rng.random() < 0.6 else 0
                if kind == 0:
                    n = int(rng.integers(1, 20))
                    pts = np.column_stack([rng.integers(0, s, n) for s in size] + [rng.integers(0, 256, n)])
                    edits.append(VoxelsEdit(pts))
                elif kind == 1:
                    lo = rng.integers(-4, np.array(size))
                    edits.append(BoxEdit(tuple(map(int, lo)), tuple(map(int, lo + rng.integers(0, 8, 3))), colour))
                else:
                    c = rng.uniform(-3, np.array(size) + 3)
                    edits.append(SphereEdit(tuple(map(float, c)), float(rng.uniform(0, 6)), colour))
            world.apply_edits(edits)
            result = world.recompute()
            incremental = world.read_field()
            voxels = world.read_voxels()
            check_field(world, voxels)
            touched = {tuple(c) for c in (np.argwhere(voxels != previous)[:, ::-1] // chunk).tolist()}
            changed = result.changed_chunks
            assert touched <= {tuple(c) for c in changed.tolist()}
            covered = np.zeros(world.config.chunks[::-1], dtype=bool)  # the regions' chunks, by mask
            for region in result.regions:
                covered[region.chunk_range(chunk).slices_zyx()] = True
            assert len(changed) == result.changed_chunk_count == covered.sum()  # no chunk twice
            assert {tuple(c) for c in changed.tolist()} == {tuple(c) for c in np.argwhere(covered)[:, ::-1].tolist()}
            previous = voxels
            world.mark_all_dirty()
            world.recompute()
            assert np.array_equal(world.read_field(), incremental), f"step {step}: incremental != full"
    finally:
        world.release()


def test_incremental_region_is_local(gpu, rng):
    """A small edit far from the rest rewrites only the chunks within the cap of it."""
    world = World(gpu, WorldConfig((128, 32, 32), 16, 8))
    try:
        voxels = random_voxels(rng, (32, 32, 128), 0.01)
        world.load_voxels(voxels)
        world.recompute()
        world.apply_edits([VoxelsEdit(np.array([[3, 3, 3, 9]]))])
        result = world.recompute()
        assert result.regions and all(r.hi[0] <= 16 + 16 for r in result.regions)
        assert set(map(tuple, result.changed_chunks)) <= {(x, y, z) for x in range(2) for y in range(2) for z in range(2)}
        voxels[3, 3, 3] = 9
        check_field(world, voxels)
    finally:
        world.release()


def test_changed_chunks_of_separate_regions(gpu):
    """Two edits far apart under a small cap: two regions, each chunk of each reported once."""
    world = World(gpu, WorldConfig((128, 32, 32), 16, 4))
    try:
        # Each voxel sits at a chunk corner, so its cap-4 neighbourhood spans 2x2x2 chunks.
        world.apply_edits([VoxelsEdit(np.array([[15, 15, 15, 9], [112, 16, 16, 9]]))])
        result = world.recompute()
        assert len(result.regions) == 2
        expected = {(x + dx, y, z) for x, y, z in np.ndindex(2, 2, 2) for dx in (0, 6)}
        assert {tuple(c) for c in result.changed_chunks.tolist()} == expected
        assert len(result.changed_chunks) == result.changed_chunk_count == len(expected)
    finally:
        world.release()


# (chunk, world size xyz, density range): up to 64^3, regions crossing chunk borders.
JFA_WORLDS = [(8, (48, 32, 40), (0.0005, 0.005)), (16, (32, 32, 32), (0.005, 0.05)),
              (16, (64, 64, 64), (0.0002, 0.002)), (32, (64, 32, 64), (0.02, 0.2))]


@pytest.mark.parametrize("algorithm", JFA)
@pytest.mark.parametrize("chunk,size,density", JFA_WORLDS)
def test_jfa_is_an_upper_bound_and_nearly_exact(gpu, rng, algorithm, chunk, size, density):
    """Jump flooding never goes below the truth (it can only overestimate), and with 26
    neighbours per step at least 99% of voxels are exact with errors of at most 2. Six face
    neighbours per step left 17-46% exact on such worlds."""
    world = World(gpu, WorldConfig(size, chunk, 255, algorithm))
    try:
        voxels = random_voxels(rng, size[::-1], rng.uniform(*density))
        world.load_voxels(voxels)
        world.recompute()
        got = world.read_distance().astype(int)
        error = got - oracle(voxels, 255).astype(int)
        assert (error >= 0).all(), f"{(error < 0).sum()} voxels below the truth"
        assert (got[voxels > 0] == 0).all()
        share = (error == 0).mean()
        assert share >= 0.99 and error.max() <= 2, f"{100 * share:.2f}% exact, max error {error.max()}"
        assert np.array_equal(world.read_field() & 0xFF, voxels)
    finally:
        world.release()


@pytest.mark.parametrize("algorithm", JFA)
def test_jfa_incremental_stays_an_upper_bound(gpu, rng, algorithm):
    """Seeded regions flood from the seed shell's distances: still never below the truth."""
    size = (48, 32, 32)
    world = World(gpu, WorldConfig(size, 16, 40, algorithm))
    try:
        world.load_voxels(random_voxels(rng, size[::-1], 0.003))
        world.recompute()
        for _ in range(4):
            world.apply_edits([SphereEdit(tuple(map(float, rng.uniform(0, 48, 3))), float(rng.uniform(1, 4)),
                                          int(rng.integers(0, 256)))])
            world.recompute()
            error = world.read_distance().astype(int) - oracle(world.read_voxels(), 40).astype(int)
            assert (error >= 0).all() and (error == 0).mean() >= 0.99 and error.max() <= 2
    finally:
        world.release()


@pytest.mark.parametrize("algorithm", JFA + ["jfa_fim"])
@pytest.mark.parametrize("corner", [(0, 0, 0), (7, 7, 7), (7, 0, 3)])
def test_jfa_one_solid_in_a_corner(gpu, algorithm, corner):
    """One solid in an 8^3 world: every distance is its Manhattan distance, at most 21 (six
    face neighbours per step left 255 in places)."""
    world = World(gpu, WorldConfig((8, 8, 8), 8, 255, algorithm))
    try:
        world.apply_edits([VoxelsEdit(np.array([[*corner, 200]]))])
        world.recompute()
        z, y, x = np.indices((8, 8, 8))
        expected = np.abs(x - corner[0]) + np.abs(y - corner[1]) + np.abs(z - corner[2])
        assert np.array_equal(world.read_distance(), expected)
    finally:
        world.release()


class InitOnly:
    """A stand-in level-of-detail algorithm whose field is unmistakable: 0 on solids, the cap
    everywhere else (initial distances, no propagation)."""

    name = "init_only_for_tests"
    exact = False

    def run(self, gpu, job):
        return AlgorithmRun([init_work(gpu, job, job.buffers.work), pack_region(gpu, job, job.buffers.work)])


def test_focus_runs_each_algorithm_where_it_belongs(gpu, rng, monkeypatch):
    """Inside the focus the field is the oracle's; outside it is exactly the LOD algorithm's. Fails
    if the focus is ignored (all exact) or taken as the whole world (all the LOD algorithm's)."""
    monkeypatch.setitem(ALGORITHMS, InitOnly.name, InitOnly())
    size, cap = (64, 32, 32), 255
    world = World(gpu, WorldConfig(size, 8, cap, "exact", focus=Focus((2, 2, 2), (2, 2, 2)),
                                   lod_algorithm=InitOnly.name))
    try:
        voxels = random_voxels(rng, size[::-1], 0.003)
        world.load_voxels(voxels)
        world.recompute()
        world.apply_edits([SphereEdit(tuple(map(float, rng.uniform(0, 32, 3))), 3.0, int(rng.integers(1, 256)))])
        world.recompute()
        voxels = world.read_voxels()
        got, truth = world.read_distance(), oracle(voxels, cap)
        inside = np.zeros(voxels.shape, bool)
        inside[8:24, 8:24, 8:24] = True  # chunks 1..2 on each axis, (z, y, x)
        assert np.array_equal(got[inside], truth[inside])
        lod_field = np.where(voxels > 0, 0, cap)
        assert np.array_equal(got[~inside], lod_field[~inside])
        assert (truth[~inside] < cap).any()  # so the two differ outside
    finally:
        world.release()


@pytest.mark.parametrize("lod_algorithm", ["jfa", "jfa+1"])
def test_focus_is_exact_inside_and_upper_bound_outside(gpu, rng, lod_algorithm):
    size = (64, 32, 32)
    world = World(gpu, WorldConfig(size, 8, 255, "exact", focus=Focus((2, 2, 2), (2, 2, 2)), lod_algorithm=lod_algorithm))
    try:
        voxels = random_voxels(rng, size[::-1], 0.003)
        world.load_voxels(voxels)
        world.recompute()
        for _ in range(2):
            world.apply_edits([SphereEdit(tuple(map(float, rng.uniform(0, 32, 3))), 3.0, int(rng.integers(0, 256)))])
            world.recompute()
        voxels = world.read_voxels()
        got, truth = world.read_distance(), oracle(voxels, 255)
        inside = (slice(8, 24), slice(8, 24), slice(8, 24))  # chunks 1..2 on each axis, (z, y, x)
        assert np.array_equal(got[inside], truth[inside])
        assert (got >= truth).all()
        result = world.last_recompute
        assert result.iterations_of(lod_algorithm) > 0
        assert set(result.algorithms) == {lod_algorithm, "exact"}
    finally:
        world.release()


def test_exact_prebuild_covers_every_region_shape(gpu):
    """After prebuild, recomputing regions of any line length builds no new program."""
    from sdfserver.algorithms.exact import Exact

    exact = Exact()
    built = exact.prebuild(gpu, max_line=256)
    assert built >= 3
    before = len(gpu.programs)
    for n in (8, 24, 40, 72, 136, 200, 256):
        for position, axis in enumerate((0, 1, 2)):
            exact.launch_shape(gpu, axis, n, n, n, n, first=position == 0, last=position == 2)
    assert len(gpu.programs) == before
