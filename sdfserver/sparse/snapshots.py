"""A sparse world's whole state as a snapshot's bricks, out and back in (storage/sparse_snapshot.py
writes and reads the files): the brick table and a copy of the pools, 3 bytes a stored voxel."""

from __future__ import annotations

import numpy as np

from sdfserver import bulk
from sdfserver.errors import InvalidInput


class SparseSnapshots:
    """SparseWorld's snapshot side (it brings gpu, pool, table, brick, dirty and version)."""

    def load_voxels(self, content) -> int:
        """Replace the whole world with a snapshot's bricks (restore); raises InvalidInput for
        anything else (imports make dense worlds)."""
        from sdfserver.storage.sparse_snapshot import SparseContent

        if not isinstance(content, SparseContent) or content.brick != self.brick:
            raise InvalidInput("a sparse world loads only its own snapshot's bricks")
        count = int(content.voxels.shape[0])
        self.pool.release()
        self.table.blocks.clear()
        self.table.generation += 1
        self.pool.reserve(count)
        slots = self.pool.take(count)  # the lowest slots in order: every segment but the last is full
        if not np.array_equal(slots, np.arange(count)):
            raise RuntimeError("a fresh pool's slots are not numbered from 0")
        for k, segment in enumerate(self.pool.segments):  # one loop over segments
            rows = slice(k * self.pool.segment_bricks, min(count, k * self.pool.segment_bricks + segment.capacity))
            if rows.stop > rows.start:
                bulk.write(self.gpu, segment.voxels, np.ascontiguousarray(content.voxels[rows]))
                bulk.write(self.gpu, segment.field, np.ascontiguousarray(content.field[rows]))
        for key, block in content.blocks.items():  # one loop over kept blocks
            self.table.blocks[key] = block if isinstance(block, int) else np.where(
                block >= 0, slots[np.maximum(block, 0)], block).astype(np.int32)
        self.dirty.clear()
        self.version += 1
        return self.version

    def copy_voxels_out(self):
        """The world as it is now, for a snapshot, without waiting for the device: a
        SparseContent (the brick table and a copy of the pools) to read only after calling the
        returned ``wait`` (any thread may; ``bulk.download_later``)."""
        from sdfserver.storage.sparse_snapshot import SparseContent

        n, b = self.pool.capacity, self.brick
        voxels = np.empty((n, b, b, b), dtype=np.uint8)
        field = np.empty((n, b, b, b), dtype=np.uint16)
        blocks = {k: v if isinstance(v, int) else v.copy() for k, v in self.table.blocks.items()}
        waits = []
        try:  # every segment but the last is full, so slots index the arrays' rows
            for k, segment in enumerate(self.pool.segments):  # one loop over segments
                rows = slice(k * self.pool.segment_bricks, k * self.pool.segment_bricks + segment.capacity)
                waits.append(bulk.download_later(self.gpu, segment.voxels, voxels[rows]))
                waits.append(bulk.download_later(self.gpu, segment.field, field[rows]))
        except BaseException:
            for w in waits:
                w()
            raise

        def wait() -> None:
            for w in waits:  # each releases its staging buffer
                w()

        return SparseContent(b, blocks, voxels, field), wait
