"""The brick table mirrored on the device for readers that walk it themselves (the renderer):
``top``, one int per block of BLOCK_BRICKS^3 bricks — the block's one code (< 0) or the index of
its codes in ``blocks`` — and ``blocks``, the kept blocks' codes one after another
(kernels/render.cl, ``field_at``).

Rebuilt from the host table when it changed since the last upload: the cost follows the table's
blocks (1/4096 of the bricks, and only kept ones), not the world's voxels."""

from __future__ import annotations

import numpy as np
import pyopencl as cl

from sdfserver.gpu import GpuContext
from sdfserver.sparse.table import AIR, BLOCK_BRICKS, BrickTable


class DeviceTable:
    def __init__(self, gpu: GpuContext, table: BrickTable):
        self.gpu, self.table = gpu, table
        self.top_n = tuple(-(-b // BLOCK_BRICKS) for b in table.bricks)  # (x, y, z) blocks
        self.top: cl.Buffer | None = None
        self.blocks: cl.Buffer | None = None
        self.uploaded_generation = -1

    def current(self) -> tuple[cl.Buffer, cl.Buffer]:
        if self.uploaded_generation != self.table.generation:
            self._upload()
        return self.top, self.blocks

    def _upload(self) -> None:
        top = np.full(self.top_n[::-1], AIR, dtype=np.int32)
        arrays = []
        for key, block in self.table.blocks.items():  # one loop over kept blocks
            if isinstance(block, int):
                top[key[2], key[1], key[0]] = block
            else:
                top[key[2], key[1], key[0]] = len(arrays)
                arrays.append(block)
        blocks = np.concatenate([a.reshape(-1) for a in arrays]) if arrays else np.zeros(1, np.int32)
        self.release()
        self.top = self.gpu.upload(top)
        self.blocks = self.gpu.upload(blocks)
        self.uploaded_generation = self.table.generation

    def release(self) -> None:
        for buf in (self.top, self.blocks):
            if buf is not None:
                buf.release()
        self.top = self.blocks = None
        self.uploaded_generation = -1
