"""What every distance-field algorithm is given and returns.

An algorithm computes distances over a region R of one world and writes the
packed field there. It reads a work box W around R: either R plus a one-voxel
*seed shell* whose distances are taken from the current field (``seeded``;
exact because any shortest path from R to a solid outside W crosses the
shell), or R plus a *halo* of ``cap`` voxels computed from voxels alone (not
seeded; needed where the surrounding field is approximate). Outside the world
is air. With the world's borders "padded" (the dissertation's §4.2.1), W is R
itself and each chunk is computed alone, everything outside it solid
(``chunk``; kernels/include/chunk_padding.h).
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass, field
from functools import partial
from typing import Callable, Iterator, Protocol

import numpy as np
import pyopencl as cl

from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext
from sdfserver.gpu.launches import KernelCopies


_INT4 = struct.Struct("<4i")
_FLOAT4 = struct.Struct("<4f")


def int4(v: tuple[int, int, int], w: int = 0) -> bytes:
    """An OpenCL int4 kernel argument, as its 16 bytes: pyopencl passes a by-value vector
    argument as a buffer, and packing one costs a seventh of building a NumPy int4
    (cltypes.make_int4 goes through eval: ~35 us a call)."""
    return _INT4.pack(v[0], v[1], v[2], w)


def float4(v: tuple[float, float, float], w: float = 0.0) -> bytes:
    """An OpenCL float4 kernel argument, as its 16 bytes (see int4)."""
    return _FLOAT4.pack(v[0], v[1], v[2], w)


def grid(shape_xyz: tuple[int, int, int], local: tuple[int, int, int] = (8, 4, 4)):
    """A 3-D global size rounded up to whole work-groups."""
    return tuple(-(-max(1, n) // l) * l for n, l in zip(shape_xyz, local)), local


@dataclass
class WorldBuffers:
    """The device buffers of one world, owned by World."""

    dims: tuple[int, int, int]  # (sx, sy, sz)
    voxels: cl.Buffer  # uchar, world-sized
    field: cl.Buffer  # ushort, world-sized
    work: cl.Buffer  # uchar, world-sized scratch plus WORK_PLANE_PAD bytes per z-plane
    work2: cl.Buffer  # uchar, world-sized scratch (ping-pong, brute output)
    # uint, world-sized: jump flooding's nearest-seed ping-pong pair, allocated only for
    # worlds whose algorithms flood (World.buffer_bytes); None otherwise.
    seeds: cl.Buffer | None = None
    seeds2: cl.Buffer | None = None
    # World-sized, Euclidean worlds only (kernels/edt.cl): the transform's second-stage result (ushort)
    # and its envelope stacks (uint); `work` holds its x-stage result.
    edt_plane: cl.Buffer | None = None
    edt_stack: cl.Buffer | None = None
    # A dense world's own kernel copies, which keep their arguments between launches
    # (gpu/launches.py); None for the short-lived views a sparse world computes in.
    kernels: KernelCopies | None = None


# Work boxes start and end on multiples of this along x (or at the world's faces), so that the
# kernels load rows as aligned vectors of 8; an algorithm may ask for more (Exact.x_align).
X_ALIGN_VOX = 8
# exact lays its work box out with z-planes this many bytes further apart than a plane, so
# z rows are not a power of two apart (kernels/exact.cl); World allocates `work` with room.
WORK_PLANE_PAD = 32


def _work_box(buffers: WorldBuffers, wanted: Box, align: int = X_ALIGN_VOX) -> Box:
    """Clip to the world and widen x to multiples of ``align`` (of X_ALIGN_VOX), so rows load as
    aligned vectors.

    The extra columns are more seed shell (their field is final) or more halo:
    either way they only repeat what is true.
    """
    box = wanted.intersect(Box.of_size(buffers.dims))
    (x0, y0, z0), (x1, y1, z1) = box.lo, box.hi
    return Box((x0 // align * align, y0, z0), (min(-(-x1 // align) * align, buffers.dims[0]), y1, z1))


@dataclass
class RegionJob:
    buffers: WorldBuffers
    region: Box  # R: written
    work_box: Box  # W: read, contains R
    seeded: bool
    cap: int
    chunk: int = 0  # padded: the chunk side, each chunk computed alone; 0: chunk borders exact
    # A signed world's second run: the distance from each solid to the nearest air voxel, written
    # over R's solids (only algorithm exact runs it: WorldConfig allows signed worlds no other).
    invert: bool = False
    signed: bool = False  # either run of a signed world
    # The world's box in the buffers' coordinates (None: the buffers are the world), whose faces
    # bound a signed world's inside distances: a sparse world computes in a scratch box.
    world: Box | None = None

    @property
    def world_box(self) -> Box:
        return Box.of_size(self.buffers.dims) if self.world is None else self.world

    @classmethod
    def seeded_region(cls, buffers: WorldBuffers, region: Box, cap: int, x_align: int = X_ALIGN_VOX) -> "RegionJob":
        return cls(buffers, region, _work_box(buffers, region.grow(1), x_align), True, cap)

    @classmethod
    def halo_region(cls, buffers: WorldBuffers, region: Box, cap: int, x_align: int = X_ALIGN_VOX) -> "RegionJob":
        return cls(buffers, region, _work_box(buffers, region.grow(cap), x_align), False, cap)

    @classmethod
    def padded_region(cls, buffers: WorldBuffers, region: Box, cap: int, chunk: int) -> "RegionJob":
        """W = R, chunk-aligned: the kernels find each voxel's chunk from box coordinates."""
        if any(v % chunk for v in (*region.lo, *region.hi)):
            raise ValueError(f"a padded region must be whole chunks of {chunk}, got {region}")
        return cls(buffers, region, region, False, cap, chunk)

    @property
    def region_offset(self) -> tuple[int, int, int]:
        return tuple(r - w for r, w in zip(self.region.lo, self.work_box.lo))


def seeds_weigh_nothing(job: RegionJob) -> bool:
    """Whether every seed of ``job`` is a solid (weight 0). Only a seed shell weighs
    something (its distances from the current field), and a seeded job has one only where its
    work box is larger than its region: a whole world's work box is the world itself."""
    return job.chunk > 0 or not job.seeded or job.work_box == job.region


@dataclass
class AlgorithmRun:
    events: list[cl.Event] = field(default_factory=list)
    counted: int = 0  # the iterations known on the host (``iterations`` adds those still arriving)
    bytes_moved: int = 0  # device memory traffic the algorithm counts (exact only; see exact.py)
    # Counts the device is still copying back (an int32 host array each, and its copy's event):
    # a count made on the device (one-launch fim) is read when asked for, so that enqueueing
    # the run does not wait for it.
    arriving: list[tuple[np.ndarray, cl.Event]] = field(default_factory=list)
    # The part of its launches' device time that is this run's: a stacked run's launches serve
    # several worlds (Exact.run_slots), each of which counts its share.
    share: float = 1.0

    @property
    def iterations(self) -> int:
        """FIM passes that changed something; JFA passes. Waits for counts still arriving."""
        while self.arriving:
            counts, copied = self.arriving.pop()
            copied.wait()
            self.counted += int(counts[0])
        return self.counted

    @iterations.setter
    def iterations(self, n: int) -> None:
        self.arriving.clear()
        self.counted = n

    def count_later(self, gpu: GpuContext, buffer: cl.Buffer) -> None:
        """Add the int32 at the start of ``buffer`` to the iterations once the queue gets there."""
        counts = np.empty(1, np.int32)
        self.arriving.append((counts, cl.enqueue_copy(gpu.queue, counts, buffer, is_blocking=False)))


class Algorithm(Protocol):
    name: str
    exact: bool
    # Optional (read with getattr, default False): supports_padding — runs padded jobs
    # (RegionJob.chunk > 0); seed_scratch — needs WorldBuffers.seeds/seeds2.
    # Optional (default X_ALIGN_VOX): x_align — the multiple of voxels its work boxes' x-bounds
    # take (region_jobs.py).
    # Optional: prepare(gpu, job) -> a call that does run(gpu, job), the host work that repeats
    # done once (World keeps it while a world's dirty regions repeat; ``prepared`` below).
    # Optional: pieces(gpu, job, run, piece_s) -> Pieces, the same work cut where it may pause
    # (an iterative algorithm whose run can outlast an engine step; ``run_pieces`` below).

    def run(self, gpu: GpuContext, job: RegionJob) -> AlgorithmRun: ...


# An algorithm's work as a generator: each step enqueues launches, and each ``yield`` is a point
# where the work may pause (the device may be left idle there, and other worlds' work run)
# without changing the result. The field is written only after the last yield, so nothing read
# between pieces sees a partial result. ``piece_s``: about how long a piece may keep the device
# busy (None: the algorithm's own batching, as one uninterrupted run would use).
Pieces = Iterator[None]


def run_pieces(algorithm: Algorithm, gpu: GpuContext, job: RegionJob, run: AlgorithmRun,
               piece_s: float | None) -> Pieces:
    """``algorithm`` over ``job`` in pieces, its figures summed into ``run``; one piece where the
    algorithm cannot pause (its whole run is short: exact, conservative)."""
    pieces = getattr(algorithm, "pieces", None)
    if pieces is not None:
        yield from pieces(gpu, job, run, piece_s)
        return
    done = algorithm.run(gpu, job)
    run.events += done.events
    run.iterations += done.iterations
    run.bytes_moved += done.bytes_moved
    yield


class SlabPace:
    """How many z-planes one launch of a pass covers when the work runs in pieces: sized from
    the launches timed before it, kept across an algorithm's passes. Whole work-groups deep, so
    that slabs do not overlap."""

    def __init__(self, piece_s: float, group_depth: int = 4):
        self.piece_s, self.group_depth = piece_s, group_depth
        self.planes = group_depth
        self.plane_s = 0.0  # the last launch's time a plane

    def learn(self, planes: int, seconds: float) -> None:
        self.plane_s = max(seconds / planes, 1e-9)
        self.planes = max(self.group_depth, int(self.piece_s / self.plane_s) // self.group_depth * self.group_depth)


def slabs(run: AlgorithmRun, launch: Callable[[int, int], cl.Event], depth: int, pace: SlabPace | None) -> Pieces:
    """``launch(z0, planes)`` over z-planes 0..depth: at once without a ``pace``; else in slabs,
    each waited for and timed, a pause after each."""
    if pace is None:
        run.events.append(launch(0, depth))
        return
    z = 0
    while z < depth:
        planes = min(pace.planes, depth - z)
        started = time.perf_counter()
        event = launch(z, planes)
        run.events.append(event)
        event.wait()
        pace.learn(planes, time.perf_counter() - started)
        z += planes
        yield


def run_whole(pieces: Pieces) -> None:
    """Enqueue every piece at once (a run that is not to pause)."""
    for _ in pieces:
        pass


# init_work and pack_region move a byte or two a voxel: a work-group 32 voxels wide along x lets
# a warp read and write whole segments of a row (grid()'s 8 x 4 x 4 has a warp touch four
# rows 8 bytes at a time).
REGION_LOCAL = (32, 4, 2)


def init_work(gpu: GpuContext, job: RegionJob, target: cl.Buffer) -> cl.Event:
    w = job.work_box
    gsize, lsize = grid(w.shape_xyz, REGION_LOCAL)
    return gpu.programs.kernel("region.cl", "init_work")(
        gpu.queue, gsize, lsize,
        job.buffers.voxels, job.buffers.field, target,
        int4(job.buffers.dims), int4(w.lo), int4(w.shape_xyz),
        int4(job.region.lo), int4(job.region.hi), np.int32(job.seeded), np.int32(job.cap),
        np.int32(job.chunk),
    )


def pack_region(gpu: GpuContext, job: RegionJob, source: cl.Buffer) -> cl.Event:
    r = job.region
    gsize, lsize = grid(r.shape_xyz, REGION_LOCAL)
    return gpu.programs.kernel("region.cl", "pack_region")(
        gpu.queue, gsize, lsize,
        source, job.buffers.voxels, job.buffers.field,
        int4(job.buffers.dims), int4(job.work_box.lo), int4(job.work_box.shape_xyz),
        int4(r.lo), int4(r.shape_xyz), np.int32(job.cap),
    )


def prepared(algorithm: Algorithm, gpu: GpuContext, job: RegionJob) -> Callable[[], AlgorithmRun]:
    """A call that runs ``algorithm`` over ``job`` (its ``prepare``, where it has one)."""
    prepare = getattr(algorithm, "prepare", None)
    return prepare(gpu, job) if prepare is not None else partial(algorithm.run, gpu, job)
