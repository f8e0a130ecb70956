"""Boxes in voxel and chunk space.

Coordinates are ``(x, y, z)``, y up; arrays are C-ordered ``(z, y, x)``.
A Box is half-open: ``lo <= p < hi`` on every axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

Vec3 = tuple[int, int, int]


@dataclass(frozen=True)
class Box:
    lo: Vec3
    hi: Vec3

    @classmethod
    def of_size(cls, size: Vec3) -> "Box":
        return cls((0, 0, 0), tuple(size))

    @property
    def shape_xyz(self) -> Vec3:
        return tuple(max(0, h - l) for l, h in zip(self.lo, self.hi))

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
        return self.volume == 0

    def grow(self, by: int) -> "Box":
        return Box(tuple(v - by for v in self.lo), tuple(v + by for v in self.hi))

    def intersect(self, other: "Box") -> "Box":
        lo = tuple(max(a, b) for a, b in zip(self.lo, other.lo))
        hi = tuple(max(l, min(a, b)) for l, a, b in zip(lo, self.hi, other.hi))
        return Box(lo, hi)

    def union(self, other: "Box") -> "Box":
        return Box(
            tuple(min(a, b) for a, b in zip(self.lo, other.lo)),
            tuple(max(a, b) for a, b in zip(self.hi, other.hi)),
        )

    def overlaps(self, other: "Box") -> bool:
        return not self.intersect(other).empty

    def contains(self, other: "Box") -> bool:
        return all(a <= b for a, b in zip(self.lo, other.lo)) and all(
            a >= b for a, b in zip(self.hi, other.hi)
        )

    def snap(self, chunk_size_vox: int) -> "Box":
        """The smallest chunk-aligned box containing this one."""
        c = chunk_size_vox
        return Box(
            tuple((v // c) * c for v in self.lo),
            tuple(-((-v) // c) * c for v in self.hi),
        )

    def slices_zyx(self, origin: Vec3 = (0, 0, 0)) -> tuple[slice, slice, slice]:
        """Index a ``(z, y, x)`` array whose element 0 sits at ``origin``."""
        (x0, y0, z0), (x1, y1, z1), (ox, oy, oz) = self.lo, self.hi, origin
        return (slice(z0 - oz, z1 - oz), slice(y0 - oy, y1 - oy), slice(x0 - ox, x1 - ox))

    def chunk_range(self, chunk_size_vox: int) -> Box:
        """The chunk coordinates this box touches, as a box in chunk space."""
        snapped = self.snap(chunk_size_vox)
        return Box(
            tuple(v // chunk_size_vox for v in snapped.lo),
            tuple(v // chunk_size_vox for v in snapped.hi),
        )


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
                if box.grow(1).overlaps(other):
                    result[i] = other.union(box)
                    merged = True
                    break
            else:
                result.append(box)
        pending = result
    return pending
