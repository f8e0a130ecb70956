"""Jump flooding's weight-0 passes in blocks (kernels/jfa.cl, jfa_seed_pass4 with JFA_BX, JFA_BY,
JFA_BZ): a work-item that takes voxels a stride apart must write every voxel of the box once, with
the seed (or on the last pass the distance) that the one-voxel pass finds, ties included. Boxes
whose sides are not multiples of twice the stride leave blocks cut short at the far edges."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

from sdfserver.algorithms import jfa
from sdfserver.algorithms.base import int4

SEED_NONE = 895 | 895 << 10 | 895 << 20
UNWRITTEN = 0xFFFFFFFF  # above every packed seed (30 bits)
CAP = 200
BLOCKS = [jfa.LAYOUT.block, (1, 1, 2)]  # the default, and one axis alone
# (chunk, box x, y, z, steps): sides odd or 4 times odd, so no step's 2 x stride divides them (a
# 44-voxel box floods with steps 32 .. 1); padded boxes are whole chunks, whose blocks never cross
# a chunk.
BOXES = [(0, (44, 37, 29), (1, 2, 4, 8, 16, 32)), (0, (12, 70, 9), (4, 64)), (8, (24, 40, 16), (1, 2, 4))]


def initial_distances(rng: np.random.Generator, shape_zyx: tuple[int, int, int], chunk: int) -> np.ndarray:
    """Solids (0) among air at the cap, or with padding at a random frame distance."""
    air = rng.integers(1, CAP + 1, shape_zyx) if chunk else np.full(shape_zyx, CAP)
    return np.where(rng.random(shape_zyx) < 0.03, 0, air).astype(np.uint8)


def random_seeds(rng: np.random.Generator, work: np.ndarray) -> np.ndarray:
    """Seeds as a flood leaves them: each solid its own, each air voxel a random solid's offset
    (lengths up to the box's, so ties are many) or none."""
    zyx = np.indices(work.shape).reshape(3, -1).T
    solid = work.reshape(-1) == 0
    offsets = zyx[solid][rng.integers(0, solid.sum(), len(zyx))] - zyx
    offsets[solid] = 0
    biased = offsets + 512  # z, y, x
    packed = (biased[:, 2] | biased[:, 1] << 10 | biased[:, 0] << 20).astype(np.uint32)
    none = (rng.random(len(zyx)) < 0.1) & ~solid
    return np.where(none, np.uint32(SEED_NONE), packed).reshape(work.shape)


def run_pass(gpu, shape_xyz, step, chunk, block, first, last, work, seeds):
    """One pass over the box: the seeds it writes, or on the last pass the distances."""
    mf = cl.mem_flags
    ctx, queue = gpu.context, gpu.queue
    work_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=work)
    src = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=seeds)
    dst_host = np.full_like(seeds, UNWRITTEN)
    out_host = np.full(work.shape, 255, np.uint8)  # above the cap: a distance never written
    dst = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=dst_host)
    out = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=out_host)
    layout = jfa.PassLayout(block=block or (1, 1, 1))
    kernel, gsize, lsize = jfa.pass_kernel(gpu, shape_xyz, step, chunk, layout, block is not None, False, 0,
                                           first, last)
    kernel(queue, gsize, lsize, work_buf, src, dst, out, int4(shape_xyz), np.int32(CAP), np.int32(chunk))
    result = out_host if last else dst_host
    cl.enqueue_copy(queue, result, out if last else dst)
    queue.finish()
    return result


@pytest.mark.parametrize("chunk,shape_xyz,steps", BOXES)
def test_block_passes_write_what_the_voxel_pass_writes(gpu, rng, chunk, shape_xyz, steps):
    shape_zyx = shape_xyz[::-1]
    for step in steps:
        # Every step between others; the first pass (initial distances in, seeds out) and the
        # last (seeds in, distances out) at two steps each, the box's first and last among them.
        kinds = [(False, False)] + [(True, False)] * (step in steps[-2:]) + [(False, True)] * (step in steps[:2])
        for first, last in kinds:
            work = initial_distances(rng, shape_zyx, chunk)
            seeds = random_seeds(rng, work)
            voxel = run_pass(gpu, shape_xyz, step, chunk, None, first, last, work, seeds)
            assert (voxel != (255 if last else UNWRITTEN)).all()
            for block in BLOCKS:
                blocked = run_pass(gpu, shape_xyz, step, chunk, block, first, last, work, seeds)
                differ = int((blocked != voxel).sum())
                assert differ == 0, f"step {step}, first {first}, last {last}, block {block}: {differ} voxels differ"


def test_blocks_cut_short_at_the_far_edges():
    """Items along an axis: whole blocks of 2 x stride, then what is left of the last one."""
    assert jfa.block_items(37, 16, 2) == 16 + 5  # one whole block of 32, then 5 alone
    assert jfa.block_items(29, 8, 2) == 8 + 8  # one whole block of 16, then 13: 8 items, 5 with partners
    assert jfa.block_items(9, 64, 2) == 9
    assert jfa.pass_block(jfa.PassLayout(block=(2, 2, 2)), (12, 70, 9), 4, 0) == ((2, 2, 2), (2, 36, 5))
    # A side no longer than the stride, or a padded chunk that is not a multiple of twice it: 1.
    assert jfa.pass_block(jfa.PassLayout(block=(2, 2, 2)), (12, 70, 9), 64, 0) == ((1, 2, 1), (3, 64, 9))
    assert jfa.pass_block(jfa.PassLayout(block=(2, 2, 2)), (48, 48, 48), 8, 8) == ((1, 1, 1), (12, 48, 48))
    # a box too small to fill the device takes no blocks (the default layout)
    assert jfa.pass_block(jfa.LAYOUT, (64, 64, 64), 8, 0) == ((1, 1, 1), (16, 64, 64))
    assert jfa.pass_block(jfa.LAYOUT, (128, 128, 128), 8, 0)[0] == (2, 2, 2)


def test_a_world_flooding_in_blocks_and_in_pieces_gets_the_field_it_gets_without_them(gpu, rng, monkeypatch):
    """A world's own `jfa` recompute with blocks forced on (its box is below the default's
    threshold), whole and cut into slabs of item rows between pauses (a recompute in pieces),
    writes the field that the flood without blocks writes."""
    import sdfserver.world as world_module
    from sdfserver.edits import parse_edits
    from sdfserver.world import World, WorldConfig

    size = (48, 32, 48)
    edits = [{"op": "sphere", "center": [float(rng.uniform(0, s)) for s in size], "radius": float(rng.uniform(1, 5)),
              "colour": 1 + int(rng.integers(0, 255))} for _ in range(12)]
    monkeypatch.setattr(world_module, "SLICE_ABOVE_VISITS", 0)  # every recompute may be cut
    fields = []
    for layout, piece_s in ((jfa.PassLayout(), None), (jfa.PassLayout(min_items=0), None),
                            (jfa.PassLayout(min_items=0), 1e-9)):
        monkeypatch.setattr(jfa, "LAYOUT", layout)
        world = World(gpu, WorldConfig(size, 16, algorithm="jfa"))
        try:
            world.apply_edits(parse_edits(edits))
            pending = world.begin_recompute(piece_s)
            assert pending.in_pieces == (piece_s is not None)
            while not pending.advance(0.0):
                pass
            pending.finish()
            fields.append(world.read_field())
        finally:
            world.release()
    assert jfa.pass_block(jfa.PassLayout(min_items=0), size, 8, 0)[0] == (2, 2, 2)
    assert np.array_equal(fields[1], fields[0]) and np.array_equal(fields[2], fields[0])
