"""A starting scene: a floor and a few shapes, as edit operations in their wire form.

Used by the render benchmark; the web demo builds the same scene in
``sdfserver/web/static/scene.js`` when it creates its default world.
"""

from __future__ import annotations

from typing import Any

GRASS, STONE, RED, BLUE, YELLOW, WHITE = 0b010_101_00, 0b100_100_10, 0b111_001_00, 0b001_010_11, 0b111_110_00, 0xFF


def demo_scene(size: tuple[int, int, int]) -> list[dict[str, Any]]:
    sx, sy, sz = size
    floor = max(1, sy // 16)
    u = max(2, min(sx, sz) // 8)  # a scene unit
    cx, cz = sx // 2, sz // 2
    return [
        {"op": "box", "min": [0, 0, 0], "max": [sx, floor, sz], "colour": GRASS},
        {"op": "sphere", "center": [cx, floor + 1.5 * u, cz], "radius": 1.5 * u, "colour": RED},
        {"op": "box", "min": [cx - 3 * u, floor, cz - 3 * u], "max": [cx - u, floor + 2 * u, cz - u],
         "colour": BLUE},
        {"op": "box", "min": [cx + 2 * u, floor, cz - 3 * u], "max": [cx + 2 * u + max(1, u // 2), floor + 4 * u,
                                                                        cz - 3 * u + max(1, u // 2)],
         "colour": STONE},
        {"op": "sphere", "center": [cx + 2 * u, floor + u, cz + 2 * u], "radius": u, "colour": YELLOW},
        {"op": "box", "min": [cx - 3 * u, floor, cz + 2 * u], "max": [cx - 2 * u, floor + 3 * u, cz + 3 * u],
         "colour": WHITE},
    ]
