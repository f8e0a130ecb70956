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

BLOCK_CODES = 16 ** 3  # sparse/table.py's BLOCK_BRICKS cubed


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
        blocks[(int(kx), int(ky), int(kz))] = int(codes[0]) if n == 1 else codes.reshape((16, 16, 16))
    size = brick ** 3
    voxels = np.frombuffer(view[at:at + bricks * size], dtype=np.uint8).reshape(bricks, brick, brick, brick)
    field = np.frombuffer(view[at + bricks * size:at + 3 * bricks * size], dtype="<u2").reshape(
        bricks, brick, brick, brick)
    return SparseContent(brick, blocks, voxels, field.astype(np.uint16), np.arange(bricks))
