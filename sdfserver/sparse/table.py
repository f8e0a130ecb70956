"""A sparse world's brick table: where each brick lives, on the host.

A brick is one chunk. Its code (an int32) is a slot in the brick pools (>= 0), ``AIR`` (every
voxel air, every distance at the cap) or ``solid_code(c)`` (every voxel solid of colour c); the
two uniform kinds take no device memory (kernels/bricks.cl reads the same codes).

A flat table over a 65536 x 4096 x 65536 world of 32-voxel bricks would hold 2^33 entries, so
the table has two levels: blocks of ``BLOCK_BRICKS``^3 codes, kept in a dict by block
coordinates; a block that is all air is not kept, and one whose bricks all share a code (the
solid rock under a terrain) is kept as that one code. Looking up a box of bricks loops over the
blocks it meets (one loop over blocks, never over bricks or voxels)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from sdfserver.geometry import Box, Vec3

AIR = -1
BLOCK_BRICKS = 16


def solid_code(colour: np.ndarray | int):
    return -2 - colour


def colour_of(code: np.ndarray | int):
    """The colour of a solid code (0 for AIR)."""
    return np.where(np.asarray(code) <= -2, -2 - np.asarray(code), 0)


class BrickTable:
    def __init__(self, bricks: Vec3):
        self.bricks = bricks  # (bx, by, bz) bricks a side
        self.blocks: dict[Vec3, np.ndarray | int] = {}  # block (x, y, z) -> codes (z, y, x) or one code
        self.generation = 0  # counts changes: the device mirror uploads again when it moved

    def _blocks_meeting(self, box: Box) -> Iterator[tuple[Vec3, tuple[slice, ...], tuple[slice, ...]]]:
        """For each block meeting ``box`` (brick coordinates): its key, the block's part in the
        box (slices into the block) and where that part goes in the box's array (slices)."""
        b = BLOCK_BRICKS
        lo_block = tuple(v // b for v in box.lo)
        hi_block = tuple(-(-v // b) for v in box.hi)
        for kz in range(lo_block[2], hi_block[2]):
            for ky in range(lo_block[1], hi_block[1]):
                for kx in range(lo_block[0], hi_block[0]):
                    key = (kx, ky, kz)
                    part = Box(tuple(k * b for k in key), tuple(k * b + b for k in key)).intersect(box)
                    in_block = part.slices_zyx(tuple(k * b for k in key))
                    yield key, in_block, part.slices_zyx(box.lo)

    def get(self, box: Box) -> np.ndarray:
        """The codes of a box of bricks, (z, y, x) int32."""
        out = np.full(box.shape_zyx, AIR, dtype=np.int32)
        for key, in_block, in_box in self._blocks_meeting(box):
            block = self.blocks.get(key)
            if isinstance(block, int):
                out[in_box] = block
            elif block is not None:
                out[in_box] = block[in_block]
        return out

    def set(self, box: Box, codes: np.ndarray) -> None:
        self.generation += 1
        for key, in_block, in_box in self._blocks_meeting(box):
            block = self.blocks.get(key, AIR)
            part = codes[in_box]
            if isinstance(block, int):
                if (part == block).all():
                    continue
                block = np.full((BLOCK_BRICKS,) * 3, block, dtype=np.int32)
            block[in_block] = part
            if (block == block.flat[0]).all():
                block = int(block.flat[0])
            if isinstance(block, int) and block == AIR:
                self.blocks.pop(key, None)
            else:
                self.blocks[key] = block

    def items(self) -> Iterator[tuple[Box, np.ndarray]]:
        """Every kept block as (its box of bricks clipped to the world, its codes): a snapshot's
        or a description's walk over what is not air."""
        b = BLOCK_BRICKS
        world = Box.of_size(self.bricks)
        for key, block in self.blocks.items():
            box = Box(tuple(k * b for k in key), tuple(k * b + b for k in key)).intersect(world)
            if isinstance(block, int):
                yield box, np.full(box.shape_zyx, block, dtype=np.int32)
            else:
                yield box, block[box.slices_zyx(tuple(k * b for k in key))]
