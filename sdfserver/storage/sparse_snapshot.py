"""A sparse world's snapshot body (format 2 of ``snapshot.py``): its brick table and its stored
bricks, voxels and field, so the snapshot's size follows the stored bricks, not the world.

Raw body (before zlib), little-endian::

    blocks: per kept table block, int32 kx, ky, kz, n (n = 1: one code follows; n = 16^3: the
            block's codes, z, y, x), then the codes; a stored brick's code is its index among
            the snapshot's bricks
    bricks: voxels of every stored brick (uint8, brick^3 each, z, y, x), then their field
            (uint16 (distance << 8) | colour)

The header's ``blocks_bytes`` and ``bricks`` bound the inflated size before anything is inflated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BLOCK_CODES_SIDE = 16  # sparse/table.py's BLOCK_BRICKS
BLOCK_CODES = BLOCK_CODES_SIDE ** 3


@dataclass
class SparseContent:
    """What a sparse world's snapshot holds. ``voxels``/``field``: (bricks, b, b, b) arrays whose
    rows ``used`` are the stored bricks (a whole pool's copy; rows past ``used`` are ignored);
    ``blocks``: the table's kept blocks, codes naming rows of ``voxels``."""

    brick: int
    blocks: dict[tuple[int, int, int], np.ndarray | int]
    voxels: np.ndarray
    field: np.ndarray
    used: np.ndarray | None = None  # rows of voxels/field that are stored bricks, in code order

    def compact(self) -> tuple[bytes, int]:
        """(the blocks' bytes with codes renumbered 0..n-1, n): bricks follow in that order."""
        used = np.unique(np.concatenate([b[b >= 0].ravel() for b in self.blocks.values()
                                         if not isinstance(b, int)] + [np.zeros(0, np.int32)]))
        self.used = used
        renumber = np.full(max(1, int(used.max()) + 1 if used.size else 1), -1, dtype=np.int64)
        renumber[used] = np.arange(used.size)
        parts = []
        for key, block in self.blocks.items():  # one loop over kept blocks
            if isinstance(block, int):
                parts.append(np.array([*key, 1, block], dtype="<i4").tobytes())
            else:
                codes = np.where(block >= 0, renumber[np.maximum(block, 0)], block).astype("<i4")
                parts.append(np.array([*key, BLOCK_CODES], dtype="<i4").tobytes() + codes.tobytes())
        return b"".join(parts), int(used.size)

    def brick_bytes(self) -> list[bytes]:
        rows = self.used if self.used is not None else np.arange(0)
        return [np.ascontiguousarray(self.voxels[rows]).tobytes(),
                np.ascontiguousarray(self.field[rows]).astype("<u2").tobytes()]


def parse_sparse(raw: bytes, blocks_bytes: int, bricks: int, brick: int, fail) -> SparseContent:
    """The content of an inflated raw body (sizes already checked against the header)."""
    view = memoryview(raw)
    blocks: dict[tuple[int, int, int], np.ndarray | int] = {}
    at = 0
    while at < blocks_bytes:  # one loop over kept blocks
        if at + 16 > blocks_bytes:
            raise fail(at, "truncated block record")
        kx, ky, kz, n = np.frombuffer(view[at:at + 16], dtype="<i4")
        at += 16
        if n not in (1, BLOCK_CODES) or at + 4 * n > blocks_bytes:
            raise fail(at, f"bad block record of {n} codes")
        codes = np.frombuffer(view[at:at + 4 * n], dtype="<i4").astype(np.int32)
        at += 4 * n
        if (codes >= bricks).any() or (codes < -257).any():
            raise fail(at, "a block names a brick the snapshot does not hold")
        key = (int(kx), int(ky), int(kz))
        if key in blocks:
            raise fail(at, f"block {list(key)} appears twice")
        blocks[key] = int(codes[0]) if n == 1 else codes.reshape((16, 16, 16))
    size = brick ** 3
    voxels = np.frombuffer(view[at:at + bricks * size], dtype=np.uint8).reshape(bricks, brick, brick, brick)
    field = np.frombuffer(view[at + bricks * size:at + 3 * bricks * size], dtype="<u2").reshape(
        bricks, brick, brick, brick)
    return SparseContent(brick, blocks, voxels, field.astype(np.uint16), np.arange(bricks))


def check_upload(content: SparseContent, size: tuple[int, int, int], cap: int, fail) -> None:
    """Refuse (``fail(reason)``) a sparse snapshot a client sent unless its bricks are a world of
    ``size`` whose field is exactly the capped Manhattan distance of its voxels: blocks inside the
    world's table, uniform blocks with uniform codes, every stored brick named exactly once and
    inside the world (two bricks sharing a slot would change together), no solid brick of colour
    0, each stored brick's colours its voxels' and
    each of its voxels 0 on a solid and min(cap, 1 + its least face neighbour) on air (neighbours in
    other bricks, stored or implicit, included), and no implicit air brick where that fails for it
    (beside an implicit solid brick, or a stored voxel nearer than cap - 1)."""
    b = content.brick
    dims = [-(-(s // b) // BLOCK_CODES_SIDE) for s in size]
    grid = _BrickGrid(content, [s // b for s in size])
    named = np.zeros(int(content.voxels.shape[0]), dtype=np.int64)
    for key, block in content.blocks.items():  # one loop over kept blocks
        if not all(0 <= k < n for k, n in zip(key, dims)):
            raise fail(f"block {list(key)} lies outside the world's {dims} blocks")
        codes = np.asarray(block)
        if (codes == SOLID_AIR_CODE).any():
            raise fail(f"block {list(key)} holds a solid brick of colour 0 (air)")
        if isinstance(block, int):
            if block >= 0:
                raise fail(f"block {list(key)} is uniform but names a stored brick")
            continue
        beyond = grid.outside([k * BLOCK_CODES_SIDE for k in key], BLOCK_CODES_SIDE)
        if (beyond & (codes >= 0)).any():  # uniform codes there are harmless: never read
            raise fail(f"block {list(key)} stores a brick beyond the world's side")
        np.add.at(named, codes[codes >= 0], 1)
    if (named != 1).any():  # two bricks sharing a slot would change together
        which = int(np.flatnonzero(named != 1)[0])
        raise fail(f"stored brick {which} is named {int(named[which])} times by the brick table; each once")
    for key in content.blocks:
        codes = grid.codes_around(key)  # the block's codes, one brick of its neighbours around
        inner = codes[1:-1, 1:-1, 1:-1]
        air = inner == AIR_CODE
        for axis in range(3):
            for shift in (-1, 1):
                beside = np.roll(codes, shift, axis=axis)[1:-1, 1:-1, 1:-1]
                if cap > 1 and (air & (beside <= -2) & (beside >= -257)).any():
                    raise fail(f"block {list(key)}: an implicit air brick lies beside an implicit solid one")
    for row, where in grid.stored_bricks():  # one loop over stored bricks
        _check_brick(content, grid, row, where, cap, fail)


AIR_CODE = -1
SOLID_AIR_CODE = -2  # "solid of colour 0": not a brick any world holds
OUTSIDE_CODE = -(1 << 20)  # a brick beyond the world's side, in a block that reaches past it


class _BrickGrid:
    """The codes of a sparse snapshot's bricks by brick coordinates (missing blocks are air)."""

    def __init__(self, content: SparseContent, bricks: list[int]):
        self.content = content
        self.bricks = bricks

    def code(self, x: int, y: int, z: int) -> int | None:
        """A brick's code; None outside the world."""
        if not (0 <= x < self.bricks[0] and 0 <= y < self.bricks[1] and 0 <= z < self.bricks[2]):
            return None
        n = BLOCK_CODES_SIDE
        block = self.content.blocks.get((x // n, y // n, z // n), AIR_CODE)
        return block if isinstance(block, int) else int(block[z % n, y % n, x % n])

    def block_codes(self, key: tuple[int, int, int]) -> np.ndarray | None:
        """A block's (16, 16, 16) codes (z, y, x); None outside the world (counted as air)."""
        n = BLOCK_CODES_SIDE
        if not all(0 <= k * n < m for k, m in zip(key, self.bricks)):
            return None
        block = self.content.blocks.get(key, AIR_CODE)
        return np.full((n, n, n), block, dtype=np.int64) if isinstance(block, int) else block.astype(np.int64)

    def outside(self, lo: list[int], side: int) -> np.ndarray:
        """(side, side, side) (z, y, x): which bricks of the cube at brick ``lo`` lie beyond the
        world's sides."""
        z, y, x = np.ogrid[lo[2]:lo[2] + side, lo[1]:lo[1] + side, lo[0]:lo[0] + side]
        beyond = ((x < 0) | (x >= self.bricks[0]) | (y < 0) | (y >= self.bricks[1]) | (z < 0)
                  | (z >= self.bricks[2]))
        return np.broadcast_to(beyond, (side, side, side))

    def codes_around(self, key: tuple[int, int, int]) -> np.ndarray:
        """(18, 18, 18) codes (z, y, x) of a block and the face layers of its six neighbours (the
        edges and corners stay air: only face neighbours are compared)."""
        n = BLOCK_CODES_SIDE
        out = np.full((n + 2, n + 2, n + 2), AIR_CODE, dtype=np.int64)
        out[1:-1, 1:-1, 1:-1] = self.block_codes(key)
        for axis in range(3):  # x, y, z; arrays are (z, y, x)
            for sign in (-1, 1):
                other = list(key)
                other[axis] += sign
                codes = self.block_codes(tuple(other))
                if codes is None:
                    continue
                index = [slice(1, -1)] * 3
                index[2 - axis] = n + 1 if sign > 0 else 0
                out[tuple(index)] = np.take(codes, 0 if sign > 0 else n - 1, axis=2 - axis)
        out[self.outside([k * n - 1 for k in key], n + 2)] = OUTSIDE_CODE
        return out

    def stored_bricks(self):
        n = BLOCK_CODES_SIDE
        for (kx, ky, kz), block in self.content.blocks.items():
            if isinstance(block, int):
                continue
            for z, y, x in np.argwhere(block >= 0):
                yield int(block[z, y, x]), (kx * n + int(x), ky * n + int(y), kz * n + int(z))

    def field_of(self, where: tuple[int, int, int], cap: int) -> np.ndarray | None:
        """A neighbouring brick's field, stored or implicit; None outside the world."""
        code = self.code(*where)
        if code is None:
            return None
        b = self.content.brick
        if code >= 0:
            return self.content.field[code]
        if code == AIR_CODE:
            return np.full((b, b, b), cap << 8, dtype=np.uint16)
        return np.full((b, b, b), -2 - code, dtype=np.uint16)


def _check_brick(content: SparseContent, grid: _BrickGrid, row: int, where: tuple[int, int, int], cap: int,
                 fail) -> None:
    voxels, field = content.voxels[row], content.field[row].astype(np.int64)
    if ((field & 0xFF) != voxels).any():
        raise fail(f"brick {list(where)}: its field's colours are not its voxels")
    distance = field >> 8
    b = content.brick
    big = 1 << 20  # beyond the world: no neighbour
    padded = np.full((b + 2, b + 2, b + 2), big, dtype=np.int64)
    padded[1:-1, 1:-1, 1:-1] = distance
    x, y, z = where
    for axis, (dx, dy, dz) in enumerate(((1, 0, 0), (0, 1, 0), (0, 0, 1))):
        for sign in (-1, 1):
            other = grid.field_of((x + sign * dx, y + sign * dy, z + sign * dz), cap)
            if other is None:
                continue
            face = np.take(other.astype(np.int64) >> 8, 0 if sign > 0 else b - 1, axis=2 - axis)
            index = [slice(1, -1)] * 3
            index[2 - axis] = b + 1 if sign > 0 else 0
            padded[tuple(index)] = face
            mine = np.take(distance, b - 1 if sign > 0 else 0, axis=2 - axis)
            if grid.code(x + sign * dx, y + sign * dy, z + sign * dz) == AIR_CODE and (mine < cap - 1).any():
                raise fail(f"brick {list(where)}: a voxel nearer than the cap lies beside an implicit air brick")
    nearest = np.minimum.reduce([padded[1 + dz:b + 1 + dz, 1 + dy:b + 1 + dy, 1 + dx:b + 1 + dx]
                                 for dx, dy, dz in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0),
                                                    (0, 0, 1), (0, 0, -1))])
    expected = np.where(voxels != 0, 0, np.minimum(cap, nearest + 1))
    if (distance != expected).any():
        bad = tuple(int(v) for v in np.argwhere(distance != expected)[0][::-1])
        raise fail(f"brick {list(where)}: the field at voxel {list(bad)} of the brick is not the capped "
                   "distance of the voxels")
