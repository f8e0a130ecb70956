"""The algorithm runs that recompute one region of a dense world, in order, from its
configuration: the world's algorithm over the region (seeded by the field around it, or each
chunk alone with padded borders); a signed world's second run inside the solids; and with a
focus, the level-of-detail algorithm over the region, then the world's own inside the focus."""

from __future__ import annotations

from dataclasses import replace
from typing import Iterator

from sdfserver.algorithms import Algorithm, RegionJob, WorldBuffers, get_algorithm
from sdfserver.algorithms.base import X_ALIGN_VOX
from sdfserver.geometry import Box
from sdfserver.world_config import WorldConfig


def region_jobs(cfg: WorldConfig, b: WorldBuffers, world_box: Box, region: Box) -> Iterator[tuple[Algorithm, RegionJob]]:
    """(algorithm, job) pairs that recompute ``region``, in order."""
    focus = None
    if cfg.focus is not None:
        focus = Box(*(tuple(c * cfg.chunk_size for c in v) for v in
                      (cfg.focus.chunk_box().lo, cfg.focus.chunk_box().hi))).intersect(world_box)
        if focus.contains(world_box):
            focus = None
    algorithm, cap = get_algorithm(cfg.algorithm), cfg.max_distance
    if cfg.borders == "padded":  # chunks alone: no shell, no halo; the focus only picks the algorithm
        seeded = halo = lambda r, a=None: RegionJob.padded_region(b, r, cap, cfg.chunk_size)  # noqa: E731
    else:
        seeded = lambda r, a=algorithm: RegionJob.seeded_region(b, r, cap, x_align(a))  # noqa: E731
        halo = lambda r, a=algorithm: RegionJob.halo_region(b, r, cap, x_align(a))  # noqa: E731
    if focus is None:
        if not cfg.signed:
            yield algorithm, seeded(region)
            return
        job = replace(seeded(region), signed=True)
        yield algorithm, job
        # inside the solids: distances to air, after the plain run wrote R
        yield algorithm, replace(job, invert=True)
        return
    # Level of detail (the dissertation's Algorithm 7): the cheap algorithm everywhere,
    # then the world's algorithm inside the focus, from voxels alone so that the
    # approximate field around it cannot leak in. Outside the focus the field is the
    # cheap algorithm's: with jump flooding an overestimate, which a ray can step past.
    lod = get_algorithm(cfg.lod_algorithm)
    yield lod, seeded(region, lod)
    inner = region.intersect(focus)
    if not inner.empty:
        yield algorithm, halo(inner)


def x_align(algorithm: Algorithm) -> int:
    """The multiple of voxels ``algorithm``'s work boxes take along x (Algorithm's x_align)."""
    return getattr(algorithm, "x_align", X_ALIGN_VOX)
