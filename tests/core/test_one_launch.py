"""Small boxes in one launch (sdfserver/algorithms/one_launch.py): fim, jump flooding and jfa_fim
give the multi-launch algorithms' field voxel for voxel (and the oracle's where they are exact),
in one or two launches instead of one a pass; a box that does not fit falls back to a launch a
pass, and padded regions in pieces are cut between their chunks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sdfserver import bulk
from sdfserver import world as world_module
from sdfserver.algorithms import ALGORITHMS
from sdfserver.algorithms import one_launch
from sdfserver.algorithms.base import AlgorithmRun, RegionJob
from sdfserver.algorithms.fim import Fim
from sdfserver.algorithms.jfa import Jfa, step_sizes
from sdfserver.algorithms.jfa_fim import JfaFim
from sdfserver.edits import SphereEdit
from sdfserver.geometry import Box
from sdfserver.world import Focus, World, WorldConfig

from .conftest import oracle, random_voxels
from .test_padded import padded_oracle

ONE = {"fim": Fim(), "jfa": Jfa(0), "jfa+1": Jfa(1), "jfa+2": Jfa(2), "jfa_fim": JfaFim()}
MULTI = {"fim": Fim(one_launch=False), "jfa": Jfa(0, one_launch=False), "jfa+1": Jfa(1, one_launch=False),
         "jfa+2": Jfa(2, one_launch=False), "jfa_fim": JfaFim(one_launch=False)}
EXACT = {"fim", "jfa_fim"}


@pytest.fixture(autouse=True)
def every_box_that_fits(request, monkeypatch):
    """The kernels are tried on every box that fits a work-group, not only those where one launch
    is also the faster way (``test_a_lone_group_floods_only_small_boxes`` checks that choice)."""
    if "lone_group" not in request.node.name:
        monkeypatch.setattr(one_launch, "LONE_GROUP_VOXELS",
                            dict.fromkeys((False, True), one_launch.MAX_BOX_VOXELS))


def spheres(rng: np.random.Generator, size, n: int) -> list[SphereEdit]:
    """Brushes that add and remove (colour 0), some reaching past the world's faces."""
    return [SphereEdit(tuple(map(float, rng.uniform(-2, np.array(size) + 2))), float(rng.uniform(0.5, 3)),
                       int(rng.integers(0, 256)) if rng.random() < 0.7 else 0) for _ in range(n)]


def inside(rng: np.random.Generator, size) -> list[SphereEdit]:
    """One brush that adds solids inside the world (a radius of 1 holds a voxel centre), so that
    something is recomputed."""
    return [SphereEdit(tuple(map(float, rng.uniform(0, size))), float(rng.uniform(1, 3)), int(rng.integers(1, 256)))]


def run_both(gpu, monkeypatch, config: WorldConfig, voxels: np.ndarray, batches=()):
    """The fields and recompute results of the world under the one-launch algorithms and under the
    multi-launch ones: after the load, then after each batch of edits (seeded regions)."""
    out = {}
    for name, variant in (("one", ONE), ("multi", MULTI)):
        for algorithm in {config.algorithm, config.lod_algorithm} & set(variant):
            monkeypatch.setitem(ALGORITHMS, algorithm, variant[algorithm])
        world = World(gpu, config)
        try:
            world.load_voxels(voxels)
            steps = [(world.recompute(), world.read_field())]
            for batch in batches:
                world.apply_edits(batch)
                steps.append((world.recompute(), world.read_field()))
            out[name] = steps, world.read_voxels()
        finally:
            world.release()
    return out


def assert_same(out, cap: int, exact_oracle=None) -> None:
    (one, voxels), (multi, _) = out["one"], out["multi"]
    for i, ((_, a), (_, b)) in enumerate(zip(one, multi)):
        differ = np.argwhere(a != b)
        first = tuple(differ[0]) if differ.size else None
        assert differ.size == 0, (f"step {i}: {len(differ)} voxels differ from the multi-launch field; first at "
                                  f"zyx {list(first)}: {a[first] >> 8} against {b[first] >> 8}")
    if exact_oracle is not None:
        assert np.array_equal((one[-1][1] >> 8).astype(np.uint8), exact_oracle(voxels, cap))


@pytest.mark.parametrize("algorithm", list(ONE))
@pytest.mark.parametrize("chunk", [8, 16, 32])
@pytest.mark.parametrize("cap", [3, 11, 255])
def test_one_chunk_world_equals_multi_launch(gpu, rng, monkeypatch, algorithm, chunk, cap):
    """The dissertation's Tables 4.4–4.6 set-up: a world of one chunk, regenerated, then edited."""
    size = (chunk,) * 3
    out = run_both(gpu, monkeypatch, WorldConfig(size, chunk, cap, algorithm),
                   random_voxels(rng, size[::-1], rng.uniform(0.002, 0.05)),
                   [spheres(rng, size, 2), spheres(rng, size, 3)])
    assert_same(out, cap, oracle if algorithm in EXACT else None)


@pytest.mark.parametrize("algorithm", list(ONE))
@pytest.mark.parametrize("chunk,size", [(8, (24, 16, 32)), (16, (32, 48, 32)), (32, (64, 32, 64))])
@pytest.mark.parametrize("cap", [5, 255])
def test_padded_chunks_equal_multi_launch(gpu, rng, monkeypatch, algorithm, chunk, size, cap):
    """Padded borders: one work-group a chunk, all in one launch."""
    out = run_both(gpu, monkeypatch, WorldConfig(size, chunk, cap, algorithm, borders="padded"),
                   random_voxels(rng, size[::-1], rng.uniform(0.002, 0.05)), [spheres(rng, size, 3)])
    assert_same(out, cap, (lambda v, c: padded_oracle(v, chunk, c)) if algorithm in EXACT else None)


@pytest.mark.parametrize("algorithm", list(ONE))
def test_seeded_regions_in_a_larger_world_equal_multi_launch(gpu, rng, monkeypatch, algorithm):
    """Edits under a small cap: regions of a few chunks, computed from their seed shell. Their boxes
    take one launch where they fit the device's local memory (a flood's 5 bytes a voxel of a box of
    up to 32 x 26 x 26 need more than the 48 KiB NVIDIA's OpenCL gives)."""
    size, cap = (48, 40, 32), 3
    chosen, original = [], one_launch.OneLaunch.chosen

    def spied(self, gpu, job):
        plan = original(self, gpu, job)
        chosen.append(plan is not None)
        return plan

    monkeypatch.setattr(one_launch.OneLaunch, "chosen", spied)
    out = run_both(gpu, monkeypatch, WorldConfig(size, 8, cap, algorithm), random_voxels(rng, size[::-1], 0.01),
                   [inside(rng, size) for _ in range(4)])
    assert_same(out, cap, oracle if algorithm in EXACT else None)
    assert len(chosen) == len(out["one"][0])  # a job a recompute: the load's whole world, then each region
    one_launches = chosen[1:]
    for (result, _), taken in zip(out["one"][0][1:], one_launches):  # regions of at most 3^3 chunks
        assert len(result.regions) == 1 and result.regions[0].volume <= 24 ** 3, result.regions
        assert (len(result.kernel_ms) == 1) == taken
    if algorithm == "fim" or gpu.device.local_mem_size >= 5 * 32 * 26 * 26 + 4096:
        assert all(one_launches)


@pytest.mark.parametrize("algorithm", ["fim", "jfa_fim"])
def test_focus_halo_jobs_equal_multi_launch(gpu, rng, monkeypatch, algorithm):
    """The focus: jump flooding over the region, then the world's algorithm from voxels alone
    inside the focus, over a halo of ``cap`` voxels."""
    size, cap = (48, 32, 32), 4
    config = WorldConfig(size, 8, cap, algorithm, focus=Focus((3, 2, 2), (2, 2, 2)), lod_algorithm="jfa")
    out = run_both(gpu, monkeypatch, config, random_voxels(rng, size[::-1], 0.01),
                   [spheres(rng, size, 1) for _ in range(3)])
    assert_same(out, cap)


@pytest.mark.parametrize("algorithm", list(ONE))
@pytest.mark.parametrize("borders,size,chunk", [("exact", (16, 16, 16), 16), ("exact", (8, 8, 8), 8),
                                                ("padded", (32, 32, 48), 16)])
def test_one_launch_is_taken(gpu, rng, monkeypatch, algorithm, borders, size, chunk):
    """One launch a run (two for padded fim and jfa_fim: the pass counter is zeroed first), against
    one a pass; the iterations are the multi-launch's kind of count (jfa: its passes)."""
    out = run_both(gpu, monkeypatch, WorldConfig(size, chunk, 255, algorithm, borders=borders),
                   random_voxels(rng, size[::-1], 0.01), [inside(rng, size)])
    for (one, _), (multi, _) in zip(out["one"][0], out["multi"][0]):
        launches = 2 if borders == "padded" and algorithm in EXACT else 1
        assert len(one.kernel_ms) <= launches < 5 <= len(multi.kernel_ms)
        if algorithm == "fim":  # solids are certain to be there, so some pass changes something
            assert 0 < one.iterations <= 3 * 255
        elif algorithm == "jfa_fim":  # FIM passes after the same flood: none where it was exact
            assert (one.iterations == 0) == (multi.iterations == 0)
        else:
            assert one.iterations == multi.iterations


def test_fim_counts_its_passes_on_the_device(gpu, monkeypatch):
    assert_fim_counts_its_passes(gpu, monkeypatch)


def assert_fim_counts_its_passes(gpu, monkeypatch) -> None:
    """A single solid in a corner of 16^3: the farthest voxel is 45 steps away, so at least one
    pass changes something; an empty world converges at once. One launch counts its passes, and
    the field is x + y + z."""
    from sdfserver.edits import VoxelsEdit

    monkeypatch.setitem(ALGORITHMS, "fim", ONE["fim"])
    world = World(gpu, WorldConfig((16, 16, 16), 16, 255, "fim"))
    try:
        world.mark_all_dirty()
        assert world.recompute().iterations == 0
        world.apply_edits([VoxelsEdit(np.array([[0, 0, 0, 9]]))])
        result = world.recompute()
        assert 1 <= result.iterations <= 45 and len(result.kernel_ms) == 1
        z, y, x = np.indices((16, 16, 16))
        assert np.array_equal(world.read_distance(), x + y + z)
    finally:
        world.release()


@pytest.mark.parametrize("algorithm", list(ONE))
def test_boxes_that_do_not_fit_fall_back(gpu, rng, monkeypatch, algorithm):
    """Too little local memory, a box past MAX_BOX_VOXELS, or (jump flooding) seeds past 16 bits:
    a launch a pass, and still the same field."""
    size = (16, 16, 16)
    monkeypatch.setattr(one_launch.OneLaunch, "_limits", lambda self, gpu, weighted=True, crew=False: (1024, 4095))
    out = run_both(gpu, monkeypatch, WorldConfig(size, 16, 255, algorithm), random_voxels(rng, size[::-1], 0.01))
    assert len(out["one"][0][0][0].kernel_ms) >= 6
    assert_same(out, 255)
    monkeypatch.undo()

    size = (40, 40, 24)  # 38,400 voxels, above 32^3
    out = run_both(gpu, monkeypatch, WorldConfig(size, 8, 255, algorithm), random_voxels(rng, size[::-1], 0.01))
    assert len(out["one"][0][0][0].kernel_ms) >= 6
    assert_same(out, 255)

    world = World(gpu, WorldConfig((64, 64, 64), 8, 255, algorithm))
    try:  # 40 x 34 x 18 = 24,480 voxels, but seeds of 6 + 6 + 5 bits
        job = RegionJob.seeded_region(world.buffers, Box((8, 8, 8), (32, 40, 24)), 255)
        assert job.work_box.shape_xyz == (40, 34, 18)
        assert (ONE[algorithm].small.plan(gpu, job) is None) == (algorithm != "fim")
    finally:
        world.release()


@pytest.mark.parametrize("algorithm", list(ONE))
def test_padded_region_in_pieces_is_cut_between_chunks(gpu, rng, monkeypatch, algorithm):
    """In pieces, a padded region runs a launch per run of chunks, writing scratch until the last
    piece: between pieces the field is the old one, and the end equals one run whole."""
    monkeypatch.setattr(world_module, "SLICE_ABOVE_VISITS", 0)
    monkeypatch.setitem(ALGORITHMS, algorithm, ONE[algorithm])
    size, chunk = (24, 16, 32), 8
    voxels = random_voxels(rng, size[::-1], 0.02)
    config = WorldConfig(size, chunk, 255, algorithm, borders="padded")
    cut, whole = World(gpu, config), World(gpu, config)
    try:
        for world in (cut, whole):
            world.load_voxels(voxels)
        before = cut.read_field()
        pending = cut.begin_recompute(piece_s=1e-6)
        assert pending.in_pieces
        while not pending.advance(0.0):
            assert np.array_equal(cut.read_field(), before)
        result = pending.finish(device_done=True)
        assert pending.pieces_run == 3 * 2 * 4, "one piece a chunk"
        whole.recompute()
        assert np.array_equal(cut.read_field(), whole.read_field())
        if algorithm in EXACT:
            assert np.array_equal(cut.read_distance(), padded_oracle(voxels, chunk, 255))
            if algorithm == "fim":
                assert result.iterations > 0  # the most of any chunk's, counted across the launches
        else:
            job = RegionJob.padded_region(cut.buffers, cut.world_box, 255, chunk)
            assert result.iterations == len(step_sizes(job, ONE[algorithm].extra_passes))
    finally:
        cut.release()
        whole.release()


def test_jfa_one_launch_is_an_upper_bound(gpu, rng):
    """Jump flooding in one launch, against scipy: never below the truth, solids 0."""
    size = (16, 16, 16)
    world = World(gpu, WorldConfig(size, 16, 255, "jfa"))
    try:
        voxels = random_voxels(rng, size[::-1], 0.01)
        world.load_voxels(voxels)
        assert len(world.recompute().kernel_ms) == 1
        error = world.read_distance().astype(int) - oracle(voxels, 255).astype(int)
        assert (error >= 0).all() and (error[voxels > 0] == 0).all()
    finally:
        world.release()


@pytest.mark.parametrize("algorithm", list(ONE))
@pytest.mark.parametrize("region_lo,region_hi", [((8, 8, 8), (16, 16, 16)), ((0, 8, 8), (24, 16, 16))])
def test_arbitrary_shell_weights_equal_multi_launch(gpu, rng, algorithm, region_lo, region_hi):
    """Seeded jobs whose seed shell holds arbitrary distances (seeds weighted unevenly): the same
    field in one launch as in a launch a pass, and for the exact algorithms the min-plus
    transform of the job's initial distances (jump flooding: never below it)."""
    size, cap = (32, 24, 24), 40
    world = World(gpu, WorldConfig(size, 8, cap, algorithm))
    try:
        voxels = random_voxels(rng, size[::-1], 0.002)
        weights = rng.integers(0, cap + 1, size[::-1]).astype(np.uint16)
        start = (np.where(voxels > 0, 0, weights) << 8 | voxels).astype(np.uint16)
        world.load_voxels(voxels)
        job = RegionJob.seeded_region(world.buffers, Box(region_lo, region_hi), cap)
        fields = []
        for variant in (ONE, MULTI):
            bulk.write(gpu, world.buffers.field, start)
            run = variant[algorithm].run(gpu, job)
            assert (len(run.events) == 1) == (variant is ONE)
            fields.append(world.read_field())
        assert np.array_equal(fields[0], fields[1])
        # the oracle of this job: the min-plus transform of the initial distances over the work box
        initial = np.where(voxels > 0, 0, cap).astype(np.int32)
        w = job.work_box
        inner = np.zeros(size[::-1], bool)
        inner[job.region.slices_zyx()] = True
        initial = np.where(inner, initial, np.minimum(weights, cap).astype(np.int32) * (voxels == 0))
        box = initial[w.slices_zyx()]
        truth = _min_plus(box, cap)[job.region.slices_zyx(w.lo)]
        got = (fields[0][job.region.slices_zyx()] >> 8).astype(np.int32)
        assert (got >= truth).all()
        if algorithm in EXACT:
            assert np.array_equal(got, truth)
    finally:
        world.release()


def _min_plus(initial: np.ndarray, cap: int) -> np.ndarray:
    """d(p) = min over q of initial(q) + |p - q|_1, capped: relaxed to the fixed point in NumPy."""
    d = initial.copy()
    while True:
        before = d.copy()
        for axis in range(3):
            for shift in (1, -1):
                moved = np.roll(d, shift, axis=axis) + 1
                edge = [slice(None)] * 3
                edge[axis] = 0 if shift == 1 else -1
                moved[tuple(edge)] = np.iinfo(np.int32).max
                d = np.minimum(d, moved)
        if np.array_equal(d, before):
            return np.minimum(d, cap)


@pytest.mark.parametrize("chunk", [8, 16, 32])
def test_the_hybrids_relaxation_alone_is_exact(gpu, rng, chunk):
    """jfa_fim's kernel with no jump-flooding pass: its FIM passes alone reach the oracle's field
    (jump flooding is exact on such worlds, so the whole hybrid would hide a relaxation that
    stopped early)."""
    size = (chunk,) * 3
    world = World(gpu, WorldConfig(size, chunk, 255, "jfa_fim"))
    try:
        voxels = random_voxels(rng, size[::-1], rng.uniform(0.002, 0.02))
        voxels.reshape(-1)[rng.integers(voxels.size)] = 7  # a solid at least: an empty world needs no pass
        world.load_voxels(voxels)
        # without the world's own kernel copies, as a sparse world's scratch views have none
        job = RegionJob.halo_region(replace(world.buffers, kernels=None), world.world_box, 255)
        small = ONE["jfa_fim"].small
        if small.plan(gpu, job) is None:
            pytest.skip(f"a {chunk}^3 flood does not fit this device's local memory")
        run = AlgorithmRun()
        for _ in small.pieces(gpu, job, run, small.plan(gpu, job), None, first_step=0, extra_passes=0):
            pass
        assert len(run.events) == 1 and run.iterations > 0
        assert np.array_equal(world.read_distance(), oracle(voxels, 255))
    finally:
        world.release()


def test_a_run_in_pieces_keeps_its_own_pass_count(gpu):
    """Other runs are enqueued between a run's pieces: a padded fim over empty chunks (frame
    distances only: no pass changes anything) keeps its count of 0 while a fim of one solid,
    run whole in between, counts its own passes."""
    from sdfserver.edits import VoxelsEdit

    fim = ONE["fim"]
    empty = World(gpu, WorldConfig((16, 16, 32), 8, 255, "fim", borders="padded"))
    solid = World(gpu, WorldConfig((16, 16, 16), 16, 255, "fim"))
    try:
        solid.apply_edits([VoxelsEdit(np.array([[0, 0, 0, 9]]))])
        cut_run, pieces = AlgorithmRun(), 0
        whole_runs = []
        for _ in fim.pieces(gpu, RegionJob.padded_region(empty.buffers, empty.world_box, 255, 8), cut_run, 1e-6):
            pieces += 1
            whole_runs.append(fim.run(gpu, RegionJob.halo_region(solid.buffers, solid.world_box, 255)))
        assert pieces == 2 * 2 * 4 and cut_run.iterations == 0
        assert all(r.iterations > 0 for r in whole_runs)
    finally:
        empty.release()
        solid.release()


@pytest.mark.parametrize("algorithm", ["jfa", "jfa_fim"])
def test_a_lone_group_floods_only_small_boxes(gpu, rng, algorithm):
    """One work-group runs on one compute unit: a lone box runs in one launch up to
    LONE_GROUP_VOXELS (smaller for a box that floods) and beyond it a launch a pass, or on a GPU
    one launch of a crew (test_crews.py), while padded chunks, many work-groups of one launch,
    take one launch at any chunk size."""
    def launches(name, size, chunk, borders="exact"):
        world = World(gpu, WorldConfig(size, chunk, 255, name, borders=borders))
        try:
            world.load_voxels(random_voxels(rng, size[::-1], 0.02))
            return len(world.recompute().kernel_ms)
        finally:
            world.release()

    assert 8 ** 3 <= one_launch.LONE_GROUP_VOXELS[True] < 16 ** 3 <= one_launch.LONE_GROUP_VOXELS[False] < 32 ** 3
    assert launches(algorithm, (8, 8, 8), 8) == 1
    crews = one_launch.takes_crews(gpu)
    assert (launches(algorithm, (16, 16, 16), 16) == 1) if crews else (launches(algorithm, (16, 16, 16), 16) >= 6)
    assert launches(algorithm, (32, 32, 16), 16, "padded") <= 2
    assert launches("fim", (16, 16, 16), 16) == 1
    assert (launches("fim", (32, 32, 32), 32) == 1) if crews else (launches("fim", (32, 32, 32), 32) >= 6)


@pytest.mark.parametrize("algorithm", ["jfa", "jfa+2", "jfa_fim"])
@pytest.mark.parametrize("chunk", [8, 16])
def test_the_flood_that_reads_no_weights_equals_the_one_that_does(gpu, rng, monkeypatch, algorithm, chunk):
    """A whole world's seeds are solids, so its flood is built without reading seeds' weights
    (ONE_LAUNCH_WEIGHTED=0): the same field, in one launch, as the kernel that reads them."""
    size = (chunk,) * 3
    voxels = random_voxels(rng, size[::-1], rng.uniform(0.002, 0.03))
    fields = []
    for weighs in (True, False):
        monkeypatch.setattr(one_launch, "seeds_weigh_nothing", lambda job, weighs=weighs: weighs)
        monkeypatch.setitem(ALGORITHMS, algorithm, ONE[algorithm])
        world = World(gpu, WorldConfig(size, chunk, 255, algorithm))
        try:
            world.load_voxels(voxels)
            assert len(world.recompute().kernel_ms) == 1
            fields.append(world.read_field())
        finally:
            world.release()
    assert np.array_equal(fields[0], fields[1])


def test_a_flood_whose_costs_pass_the_keys_bits_falls_back(gpu):
    """A flood ranks candidates by a key with COST_BITS for the cost: a box whose cap plus longest
    way could pass them floods a launch a pass; fim, which keeps no keys, still takes one launch."""
    world = World(gpu, WorldConfig((2048, 8, 8), 8, 255, "jfa"))
    try:
        def job(x: int, cap: int) -> RegionJob:  # a box of x * 4 * 4: seeds of 11 + 2 + 2 bits at most
            box = Box((0, 0, 0), (x, 4, 4))
            return RegionJob(world.buffers, box, box, False, cap)

        for cap in (255, 3):  # ways up to 2047 + 3 + 3
            assert ONE["jfa"].small.plan(gpu, job(2048, cap)) is None
            assert ONE["jfa_fim"].small.plan(gpu, job(2048, cap)) is None
        if gpu.device.local_mem_size >= 2048 * 16 + 64:
            assert ONE["fim"].small.plan(gpu, job(2048, 255)) is not None
        if gpu.device.local_mem_size >= 1024 * 16 * 5 + 64:  # 255 + 1023 + 6: within the bits
            assert ONE["jfa"].small.plan(gpu, job(1024, 255)) is not None
    finally:
        world.release()
