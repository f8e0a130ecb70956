"""The dissertation's benchmark mode (§3.5): an edit every 200 ms at a random position with a
random brush size, reproducible from a seed.

The generator is mulberry32 (32-bit integer arithmetic and one division by 2^32, so every number
is exact in a double): ``sdfserver/web/static/schedule.js`` is the same code in JavaScript, and a
test checks that both make the same schedule from the same seed. Each brush is half the time a
placement in a colour 1..255, half the time an erasure (colour 0).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

EDIT_INTERVAL_MS = 200.0  # the dissertation's "modification every 200ms" (Tables 4.1, 4.3)
DEFAULT_SEED = 2025
_MASK = 0xFFFFFFFF


class Mulberry32:
    """A 32-bit PRNG small enough to port: the JavaScript copy gives the same numbers."""

    def __init__(self, seed: int):
        self.state = seed & _MASK

    def next_u32(self) -> int:
        self.state = (self.state + 0x6D2B79F5) & _MASK
        t = self.state
        t = ((t ^ (t >> 15)) * (t | 1)) & _MASK
        t ^= (t + (((t ^ (t >> 7)) * (t | 61)) & _MASK)) & _MASK
        return (t ^ (t >> 14)) & _MASK

    def uniform(self) -> float:
        """A float in [0, 1)."""
        return self.next_u32() / 4294967296.0


def max_radius_vox(size: tuple[int, int, int]) -> float:
    return max(2.0, min(size) / 16)


def next_brush(rng: Mulberry32, size: tuple[int, int, int]) -> dict[str, Any]:
    """One sphere edit in its wire form; the draw order is the JavaScript copy's."""
    center = [rng.uniform() * s for s in size]
    radius = 1.0 + rng.uniform() * (max_radius_vox(size) - 1.0)
    place = rng.uniform() >= 0.5
    colour = 1 + int(rng.uniform() * 255) if place else 0
    return {"op": "sphere", "center": center, "radius": radius, "colour": colour}


@dataclass
class Schedule:
    """Brushes for a world of ``size`` from ``seed``, one every ``interval_ms``."""

    size: tuple[int, int, int]
    seed: int = DEFAULT_SEED
    interval_ms: float = EDIT_INTERVAL_MS

    def __post_init__(self) -> None:
        self._rng = Mulberry32(self.seed)

    def next(self) -> dict[str, Any]:
        return next_brush(self._rng, self.size)

    def __iter__(self) -> Iterator[dict[str, Any]]:
        while True:
            yield self.next()

    def first(self, count: int) -> list[dict[str, Any]]:
        rng = Mulberry32(self.seed)
        return [next_brush(rng, self.size) for _ in range(count)]


__all__ = ["DEFAULT_SEED", "EDIT_INTERVAL_MS", "Mulberry32", "Schedule", "max_radius_vox", "next_brush"]
