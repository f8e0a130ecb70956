"""A subscriber's single-slot mailbox and its subscription.

The engine thread ``put``s the chunks a recompute rewrote; the subscriber's
sender ``take``s whatever is pending. Updates a slow subscriber has not taken
yet are merged — newest data per chunk wins — so a mailbox never holds more
than one copy of each chunk of its region, however far behind its reader is.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable

from sdfserver.geometry import Box

ChunkKey = tuple[int, int, int]  # chunk coordinates (x, y, z)


@dataclass(frozen=True)
class Update:
    version: int  # the world version the newest chunk reflects
    chunks: dict[ChunkKey, bytes]  # chunk -> C-ordered (z, y, x) bytes in the subscription's format
    ended: str | None = None  # why no update follows (the world moved to another engine)


class Mailbox:
    def __init__(self, notify: Callable[[], None] = lambda: None):
        self._lock = threading.Lock()
        self._chunks: dict[ChunkKey, bytes] = {}
        self._version = 0
        self._notify = notify
        self._ended: str | None = None
        self.merged_chunks = 0  # chunks overwritten before they were sent

    def put(self, version: int, chunks: dict[ChunkKey, bytes]) -> int:
        """Merge ``chunks`` into the pending update; returns how many unsent chunks they replaced."""
        if not chunks:
            return 0
        with self._lock:
            was_empty = not self._chunks
            merged = len(self._chunks.keys() & chunks.keys())
            self.merged_chunks += merged
            self._chunks.update(chunks)
            self._version = max(self._version, version)
        if was_empty:
            self._notify()
        return merged

    def end(self, why: str) -> None:
        """No update follows: the last ``take`` says why (after what was still pending)."""
        with self._lock:
            was_empty, self._ended = not self._chunks, why
        if was_empty:
            self._notify()

    def take(self) -> Update | None:
        with self._lock:
            if not self._chunks and self._ended is None:
                return None
            chunks, self._chunks = self._chunks, {}
            ended, self._ended = self._ended, None
            return Update(self._version, chunks, ended)

    @property
    def pending(self) -> bool:
        """Something waits to be taken: chunks, or the news that no update follows."""
        return bool(self._chunks) or self._ended is not None

    @property
    def pending_chunks(self) -> int:
        return len(self._chunks)

    @property
    def pending_bytes(self) -> int:
        with self._lock:
            return sum(len(b) for b in self._chunks.values())


@dataclass(eq=False)
class Subscription:
    """A region of one world's field, snapped to chunks, and where its updates go."""

    world_id: str
    region: Box  # chunk-aligned voxel box
    format: str = "packed"  # "packed" (uint16) or "distance" (uint8)
    mailbox: Mailbox = field(default_factory=Mailbox)

    @property
    def dtype(self) -> str:
        return "uint16" if self.format == "packed" else "uint8"
