"""A world's dirty set: what edits may have changed since the last recompute, as world-clipped
boxes (or the whole world), and the regions and chunk count it comes to."""

from __future__ import annotations

import numpy as np

from sdfserver.geometry import Box, merge_regions
from sdfserver.world_config import WorldConfig

# Up to this many (chunk, brush) pairs a step's dirty chunks are counted in a set: numpy on the
# whole chunk mask lets go of the GIL and, with other busy threads, waits up to a switch interval
# to get it back, several times a step.
SMALL_DIRTY_CHUNKS = 4096
# From this many boxes a step's regions are grown on arrays: a few numpy calls cost less than
# the plain-int loop over that many boxes.
VECTOR_BOXES = 8


class DirtySet:
    def __init__(self) -> None:
        self.boxes: list[Box] = []
        self.all = False
        # an edit since the last recompute erased (wrote air): distances may rise, not only fall;
        # one added solids (wrote a colour): they may fall
        self.erased = False
        self.added = False

    def __bool__(self) -> bool:
        return self.all or bool(self.boxes)

    def add(self, boxes: list[Box], erases: bool = True, adds: bool = True) -> None:
        """``erases``, ``adds``: whether the edit that changed ``boxes`` may have written air, and
        solids."""
        self.boxes.extend(boxes)
        self.erased |= erases and bool(boxes)
        self.added |= adds and bool(boxes)

    def mark_all(self) -> None:
        self.all = True

    def clear(self) -> None:
        self.boxes.clear()
        self.all = False
        self.erased = self.added = False

    def regions(self, config: WorldConfig, max_regions: int = 32) -> list[Box]:
        """The regions a recompute rewrites: each box grown by the cap, snapped to chunks,
        clipped to the world, touching ones merged (past ``max_regions``, one box around them
        all: geometry.merge_regions)."""
        if self.all:
            return [Box.of_size(config.size)]
        if not self.boxes:  # a batch of edits clipped to nothing (a box past the world) dirties nothing
            return []
        cap, cs, (sx, sy, sz) = config.max_distance, config.chunk_size, config.size
        if config.borders == "padded":
            cap = 0  # each chunk is computed alone: an edit changes only the chunks it touches
        # A box that grows to the whole world swallows every other region (they all touch it):
        # under a cap near the world's side that is every box, so the first one settles it;
        # under a cap of the world's side or more, without looking (the common step of a small world).
        world = Box((0, 0, 0), (sx, sy, sz))
        if cap >= max(sx, sy, sz) or self.boxes[0].grow(cap).snap(cs).contains(world):
            return [world]
        # In plain ints (b.grow(cap).snap(cs).intersect(world) made three Boxes an edit). Under a
        # large cap many edits grow to the same region: merge each once.
        if len(self.boxes) >= VECTOR_BOXES:
            return merge_regions(self._grown_vectorized(cap, cs, config.size), max_regions)
        grown = {}
        for b in self.boxes:
            (x0, y0, z0), (x1, y1, z1) = b.lo, b.hi
            lo = (max(0, (x0 - cap) // cs * cs), max(0, (y0 - cap) // cs * cs), max(0, (z0 - cap) // cs * cs))
            hi = (max(lo[0], min(sx, -(-(x1 + cap) // cs) * cs)), max(lo[1], min(sy, -(-(y1 + cap) // cs) * cs)),
                  max(lo[2], min(sz, -(-(z1 + cap) // cs) * cs)))
            grown[lo, hi] = None
        return merge_regions((Box(lo, hi) for lo, hi in grown), max_regions)

    def _grown_vectorized(self, cap: int, cs: int, size: tuple[int, int, int]) -> list[Box]:
        """The boxes grown by ``cap``, snapped to chunks and clipped, each region once: the same
        sums as the loop in ``regions``, on arrays (a step of many brushes)."""
        corners = np.array([b.lo + b.hi for b in self.boxes], dtype=np.int64)
        lo = np.maximum(0, (corners[:, :3] - cap) // cs * cs)
        hi = np.maximum(lo, np.minimum(np.asarray(size, dtype=np.int64), -(-(corners[:, 3:] + cap) // cs) * cs))
        rows = dict.fromkeys(map(tuple, np.concatenate([lo, hi], axis=1).tolist()))
        return [Box(row[:3], row[3:]) for row in rows]

    def chunk_count(self, config: WorldConfig) -> int:
        if self.all:
            return int(np.prod(config.chunks))
        ranges = [box.chunk_range(config.chunk_size) for box in self.boxes]
        if len(ranges) == 1:  # one brush, the common step: no mask to build
            return ranges[0].volume
        if sum(r.volume for r in ranges) <= SMALL_DIRTY_CHUNKS:  # a step of brushes: a set, in Python
            return len({(x, y, z) for r in ranges for z in range(r.lo[2], r.hi[2])
                        for y in range(r.lo[1], r.hi[1]) for x in range(r.lo[0], r.hi[0])})
        mask = np.zeros(config.chunks[::-1], dtype=bool)
        for r in ranges:  # one loop over boxes, never over voxels
            mask[r.slices_zyx()] = True
        return int(mask.sum())
