"""Worlds past 2^31 voxels, tested by their mechanisms: this machine's device cannot hold one.

Fills and copies run as the project's own 64-bit kernels (kernels/bulk.cl) that loop over
whatever a launch does not cover; host transfers go in pieces; the shared index functions
are 64-bit; a world that does not fit is refused before anything is allocated."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from pydantic import ValidationError

from sdfserver import bulk
from sdfserver.edits import BoxEdit, SphereEdit
from sdfserver.errors import DeviceMemoryExceeded
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext
from sdfserver.settings import Settings
from sdfserver.world import MAX_WORLD_VOXELS, World, WorldConfig

from .conftest import oracle

DTYPES = (np.uint8, np.uint16, np.int32)


def _buffer(gpu: GpuContext, host: np.ndarray) -> cl.Buffer:
    return cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=host)


def _download(gpu: GpuContext, buf: cl.Buffer, like: np.ndarray) -> np.ndarray:
    out = np.empty_like(like)
    cl.enqueue_copy(gpu.queue, out, buf, is_blocking=True)
    return out


@pytest.mark.parametrize("dtype", DTYPES)
def test_fill_writes_every_element_up_to_the_last_and_nothing_after(gpu, rng, dtype):
    count = int(rng.integers(3 * bulk.LOCAL_SIZE + 1, 40 * bulk.LOCAL_SIZE)) | 1  # no multiple of 64
    sentinel = np.iinfo(dtype).max
    host = np.full(count + 37, sentinel, dtype=dtype)
    buf = _buffer(gpu, host)
    # One work-group of work-items: each loops over count / 64 elements.
    bulk.fill(gpu, buf, dtype, 7, count, work_items=bulk.LOCAL_SIZE)
    got = _download(gpu, buf, host)
    assert (got[:count] == 7).all() and got[count - 1] == 7
    assert (got[count:] == sentinel).all()


@pytest.mark.parametrize("dtype", DTYPES)
def test_copy_between_offsets_in_several_rounds(gpu, rng, dtype):
    info = np.iinfo(dtype)
    src_host = rng.integers(info.min, info.max, 5000, dtype=dtype, endpoint=True)
    dst_host = np.zeros(4000, dtype=dtype)
    src, dst = _buffer(gpu, src_host), _buffer(gpu, dst_host)
    count, src_first, dst_first = 2999, 1001, 555
    bulk.copy(gpu, dst, src, dtype, count, dst_first=dst_first, src_first=src_first, work_items=3 * bulk.LOCAL_SIZE)
    expected = dst_host.copy()
    expected[dst_first:dst_first + count] = src_host[src_first:src_first + count]
    assert np.array_equal(_download(gpu, dst, dst_host), expected)


def test_write_read_box_and_download_in_pieces(gpu, rng):
    dims = (40, 24, 56)  # (sx, sy, sz)
    host = rng.integers(0, 65536, dims[::-1], dtype=np.uint16)
    buf = cl.Buffer(gpu.context, cl.mem_flags.READ_WRITE, size=host.nbytes)
    bulk.write(gpu, buf, host, piece_bytes=1001)  # pieces that cut elements in half
    assert np.array_equal(_download(gpu, buf, host), host)
    box = Box((3, 5, 7), (37, 23, 50))
    plane_bytes = 34 * 18 * 2
    got = bulk.read_box(gpu, buf, np.uint16, dims, box, piece_bytes=3 * plane_bytes + 1)  # 3 planes a slab
    assert np.array_equal(got, host[box.slices_zyx()])
    out = np.empty_like(host)
    used = gpu.allocated_bytes
    wait = bulk.download_later(gpu, buf, out, piece_bytes=999)
    wait()
    assert np.array_equal(out, host) and gpu.allocated_bytes == used


def test_index_functions_are_64_bit(gpu, rng):
    """world_index and box_index at coordinates whose linear index is past 2^31 and 2^32."""
    dims = np.array([2048, 2048, 2048], dtype=np.int64)
    points = np.concatenate([
        np.array([[2047, 2047, 2047], [0, 0, 1024], [2047, 2047, 511], [5, 1024, 1536]], dtype=np.int64),
        rng.integers(0, 2048, (64, 3)),
    ])
    n = len(points)
    rows = np.zeros((n, 4), dtype=np.int32)
    rows[:, :3] = points
    world_out, box_out = (cl.Buffer(gpu.context, cl.mem_flags.WRITE_ONLY, size=8 * n) for _ in range(2))
    gpu.programs.kernel("index_check.cl", "index_of")(
        gpu.queue, (-(-n // 64) * 64,), (64,), _buffer(gpu, rows), np.array([*dims, 0], dtype=np.int32),
        np.int32(n), world_out, box_out)
    expected = (points[:, 2] * dims[1] + points[:, 1]) * dims[0] + points[:, 0]
    assert expected.max() == 2 ** 33 - 1
    for buf in (world_out, box_out):
        got = np.empty(n, dtype=np.uint64)
        cl.enqueue_copy(gpu.queue, got, buf, is_blocking=True)
        assert np.array_equal(got, expected.astype(np.uint64))


def _small_world(gpu: GpuContext, rng) -> tuple[World, np.ndarray]:
    world = World(gpu, WorldConfig(size=(32, 32, 32), chunk_size=16, max_distance=9))
    world.apply_edits([SphereEdit(center=tuple(rng.integers(0, 32, 3).tolist()), radius=5, colour=0x1C),
                       BoxEdit(min=(0, 0, 0), max=(4, 32, 4), colour=0xE0)])
    world.recompute()
    return world, world.read_field()


@pytest.mark.parametrize("limit", ["budget", "largest buffer"])
def test_world_that_does_not_fit_is_refused_and_changes_nothing(gpu, rng, limit):
    small_bytes = sum(World.buffer_bytes(WorldConfig(size=(32, 32, 32), chunk_size=16)))
    ctx = GpuContext(gpu.device, memory_budget_bytes=small_bytes * 3)
    if limit == "largest buffer":
        ctx.max_allocation_bytes = 2 * 64 ** 3 - 1  # a 64^3 field is one byte too many
    world, field = _small_world(ctx, rng)
    used = ctx.allocated_bytes
    too_big = (2048, 2048, 2048) if limit == "budget" else (64, 64, 64)
    allocations = []
    allocate = ctx.allocate
    ctx.allocate = lambda nbytes: allocations.append(nbytes) or allocate(nbytes)
    with pytest.raises(DeviceMemoryExceeded):
        World(ctx, WorldConfig(size=too_big, chunk_size=32))
    assert allocations == [], "refused only after asking for buffers"
    ctx.allocate = allocate
    assert ctx.allocated_bytes == used
    assert np.array_equal(world.read_field(), field)
    world.apply_edits([BoxEdit(min=(8, 8, 8), max=(9, 9, 9), colour=3)])
    world.recompute()
    voxels = world.read_voxels()
    assert np.array_equal(world.read_field() >> 8, oracle(voxels, 9))
    world.release()
    assert ctx.allocated_bytes == 0


def test_world_past_2_to_the_31_is_counted_in_64_bits():
    config = WorldConfig(size=(2048, 2048, 2048), chunk_size=32).validated()
    sizes = World.buffer_bytes(config)
    assert sizes[1] == 2 ** 34 and sum(sizes) == 5 * 2 ** 33 + 2048 * 32


def test_max_world_voxels_is_bounded_by_the_largest_world():
    assert Settings(max_world_voxels=MAX_WORLD_VOXELS).max_world_voxels == 2048 ** 3
    with pytest.raises(ValidationError):
        Settings(max_world_voxels=MAX_WORLD_VOXELS + 1)


def test_brush_launches_keep_their_work_items_within_32_bits(gpu, rng, monkeypatch):
    """fill_brushes counts work-items in 32 bits: a launch of several brushes covers at most
    WORK_ITEMS_PER_LAUNCH voxels, and a brush larger than that goes alone, through its own
    3-D kernel (at 2048^3 one box can cover 2^33 voxels). Shown with a small limit."""
    from sdfserver import world as world_module

    limit = 700
    monkeypatch.setattr(world_module, "WORK_ITEMS_PER_LAUNCH", limit)
    launches = []
    enqueue = World._enqueue_brushes

    def spy(self, brushes):
        launches.append([box.volume for _, box in brushes])
        enqueue(self, brushes)

    monkeypatch.setattr(World, "_enqueue_brushes", spy)
    world = World(gpu, WorldConfig(size=(32, 32, 32), chunk_size=16, max_distance=12))
    expected = np.zeros((32, 32, 32), dtype=np.uint8)
    edits = []
    for _ in range(40):
        lo = rng.integers(0, 28, 3)
        hi = np.minimum(32, lo + rng.integers(1, 16, 3))
        colour = int(rng.integers(0, 256))
        edits.append(BoxEdit(min=tuple(lo.tolist()), max=tuple(hi.tolist()), colour=colour))
        expected[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]] = colour
    world.apply_edits(edits)
    assert np.array_equal(world.read_voxels(), expected)
    launched = [volumes for volumes in launches if volumes]
    assert sum(map(len, launched)) == len(edits)
    assert any(v > limit for volumes in launched for v in volumes), "no brush above the limit: widen the boxes"
    for volumes in launched:
        assert len(volumes) == 1 or sum(volumes) <= limit, volumes
    world.recompute()
    assert np.array_equal(world.read_distance(), oracle(expected, 12))
