"""Boxes in voxel and chunk space.

Coordinates are ``(x, y, z)``, y up; arrays are C-ordered ``(z, y, x)``.
A Box is half-open: ``lo <= p < hi`` on every axis.
"""

from __future__ import annotations

from typing import Iterable

import msgspec

Vec3 = tuple[int, int, int]


class Box(msgspec.Struct, frozen=True):
    """Hot on the engine thread (several per edit): methods spell out the three axes, and it is a
    msgspec struct, made faster than a frozen dataclass."""

    lo: Vec3
    hi: Vec3

    @classmethod
    def of_size(cls, size: Vec3) -> "Box":
        return cls((0, 0, 0), tuple(size))

    @property
    def shape_xyz(self) -> Vec3:
        (x0, y0, z0), (x1, y1, z1) = self.lo, self.hi
        return (max(0, x1 - x0), max(0, y1 - y0), max(0, z1 - z0))

    @property
    def shape_zyx(self) -> Vec3:
        sx, sy, sz = self.shape_xyz
        return (sz, sy, sx)

    @property
    def volume(self) -> int:
        sx, sy, sz = self.shape_xyz
        return sx * sy * sz

    @property
    def empty(self) -> bool:
        (x0, y0, z0), (x1, y1, z1) = self.lo, self.hi
        return x1 <= x0 or y1 <= y0 or z1 <= z0

    def grow(self, by: int) -> "Box":
        (x0, y0, z0), (x1, y1, z1) = self.lo, self.hi
        return Box((x0 - by, y0 - by, z0 - by), (x1 + by, y1 + by, z1 + by))

    def intersect(self, other: "Box") -> "Box":
        (ax0, ay0, az0), (ax1, ay1, az1) = self.lo, self.hi
        (bx0, by0, bz0), (bx1, by1, bz1) = other.lo, other.hi
        lo = (max(ax0, bx0), max(ay0, by0), max(az0, bz0))
        hi = (max(lo[0], min(ax1, bx1)), max(lo[1], min(ay1, by1)), max(lo[2], min(az1, bz1)))
        return Box(lo, hi)

    def union(self, other: "Box") -> "Box":
        (ax0, ay0, az0), (ax1, ay1, az1) = self.lo, self.hi
        (bx0, by0, bz0), (bx1, by1, bz1) = other.lo, other.hi
        return Box((min(ax0, bx0), min(ay0, by0), min(az0, bz0)), (max(ax1, bx1), max(ay1, by1), max(az1, bz1)))

    def overlaps(self, other: "Box") -> bool:
        return not self.intersect(other).empty

    def contains(self, other: "Box") -> bool:
        return all(a <= b for a, b in zip(self.lo, other.lo)) and all(
            a >= b for a, b in zip(self.hi, other.hi)
        )

    def snap(self, chunk_size_vox: int) -> "Box":
        """The smallest chunk-aligned box containing this one."""
        c = chunk_size_vox
        (x0, y0, z0), (x1, y1, z1) = self.lo, self.hi
        return Box((x0 // c * c, y0 // c * c, z0 // c * c), (-(-x1 // c) * c, -(-y1 // c) * c, -(-z1 // c) * c))

    def slices_zyx(self, origin: Vec3 = (0, 0, 0)) -> tuple[slice, slice, slice]:
        """Index a ``(z, y, x)`` array whose element 0 sits at ``origin``."""
        (x0, y0, z0), (x1, y1, z1), (ox, oy, oz) = self.lo, self.hi, origin
        return (slice(z0 - oz, z1 - oz), slice(y0 - oy, y1 - oy), slice(x0 - ox, x1 - ox))

    def chunk_range(self, chunk_size_vox: int) -> Box:
        """The chunk coordinates this box touches, as a box in chunk space."""
        c = chunk_size_vox
        (x0, y0, z0), (x1, y1, z1) = self.lo, self.hi
        return Box((x0 // c, y0 // c, z0 // c), (-(-x1 // c), -(-y1 // c), -(-z1 // c)))


def merge_regions(boxes: Iterable[Box], max_regions: int = 32) -> list[Box]:
    """Merge boxes until no two of them touch.

    Two regions that overlap or share a face are replaced by their union, so
    that the one-voxel seed shell of each region lies outside every other
    region: the field read from that shell is then final. Above
    ``max_regions`` the union of all of them is returned. This loops over
    boxes, never over voxels.
    """
    pending = [b for b in boxes if not b.empty]
    if len(pending) > max_regions:
        out = pending[0]
        for b in pending[1:]:
            out = out.union(b)
        return [out]
    merged = True
    while merged:
        merged = False
        result: list[Box] = []
        for box in pending:
            for i, other in enumerate(result):
                if touch(box, other):
                    result[i] = other.union(box)
                    merged = True
                    break
            else:
                result.append(box)
        pending = result
    return pending


def touch(a: Box, b: Box) -> bool:
    """Whether two non-empty boxes overlap or share a face (``a.grow(1).overlaps(b)``), in
    plain ints: ``merge_regions`` asks it for every pair of a step's regions."""
    (ax0, ay0, az0), (ax1, ay1, az1) = a.lo, a.hi
    (bx0, by0, bz0), (bx1, by1, bz1) = b.lo, b.hi
    return ax1 >= bx0 and bx1 >= ax0 and ay1 >= by0 and by1 >= ay0 and az1 >= bz0 and bz1 >= az0
