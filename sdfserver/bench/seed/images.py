"""Figures 4.5 and 4.9: the same seeded scene rendered from fields made different ways, side by
side, with each field's error against the exact one.

Figure 4.5 sets exact beside padded chunks (§4.2.1), JFA and the conservative lower bound;
Figure 4.9 sets focus sizes 1, 2 and the whole world (JFA outside the focus) side by side. The
pictures are composed with Pillow (a dependency), so the measuring machine needs no matplotlib.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from sdfserver.bench.reference import compare
from sdfserver.bench.schedule import Schedule
from sdfserver.bench.seed.tables import figure_file
from sdfserver.edits import parse_edits
from sdfserver.render.bench import orbit, world_config
from sdfserver.render.scene import demo_scene
from sdfserver.world import World

HEADER_PX = 18
MAX_PNG_BYTES = 290_000


@dataclass(frozen=True)
class Variant:
    number: str  # the figure
    name: str
    algorithm: str
    borders: str | None = None
    focus: int | None = None
    lod_algorithm: str | None = None


def _figure_4_5(plan) -> list[Variant]:
    return [Variant("4.5", "exact", "exact"), Variant("4.5", "padded (brute)", "brute", borders="padded"),
            Variant("4.5", "jfa", "jfa"), Variant("4.5", "conservative", "conservative")]


def _figure_4_9(plan) -> list[Variant]:
    chunks = plan.image_world // plan.image_chunk
    return [Variant("4.9", f"focus {f}x{f}" if f < chunks else "focus: whole world", "jfa_fim", focus=f,
                    lod_algorithm="jfa") for f in plan.image_focus]


VARIANTS = {"4.5": _figure_4_5, "4.9": _figure_4_9}


def _scene_world(gpu, plan, seed: int, config) -> World:
    world = World(gpu, config)
    size = config.size
    world.apply_edits(parse_edits(demo_scene(size) + Schedule(size, seed).first(plan.image_brushes)))
    world.recompute()
    return world


def render_variant(gpu, renderer, plan, seed: int, variant: Variant, tiles: dict) -> dict[str, Any]:
    """Renders ``variant`` into ``tiles`` and returns its row: the field's error against exact."""
    n = plan.image_world
    config = world_config(n, variant.algorithm, chunk_size=plan.image_chunk, borders=variant.borders,
                          focus=variant.focus, lod_algorithm=variant.lod_algorithm)
    reference = _scene_world(gpu, plan, seed, world_config(n, "exact", chunk_size=plan.image_chunk))
    try:
        exact = reference.read_distance()
    finally:
        reference.release()
    world = _scene_world(gpu, plan, seed, config)
    try:
        frame = renderer.render(world, orbit(config.size, 0, plan.image_width, plan.image_height))
        row = compare(variant.algorithm, n, world.read_distance(), exact)
    finally:
        world.release()
    tiles[variant.number, variant.name] = frame.pixels[..., :3]
    return {**row, "name": variant.name, "chunk": plan.image_chunk, "borders": variant.borders or "exact",
            "focus": variant.focus, "lod": variant.lod_algorithm, "image": figure_file(variant.number)}


def _tile(pixels: np.ndarray | None, title: str, width: int, height: int) -> Image.Image:
    tile = Image.new("RGB", (width, height + HEADER_PX), (255, 255, 255))
    if pixels is None:
        ImageDraw.Draw(tile).rectangle((0, HEADER_PX, width, height + HEADER_PX), fill=(200, 200, 200))
        ImageDraw.Draw(tile).text((8, HEADER_PX + height // 2), "not available", fill=(0, 0, 0))
    else:
        tile.paste(Image.fromarray(np.ascontiguousarray(pixels)), (0, HEADER_PX))
    ImageDraw.Draw(tile).text((4, 3), title, fill=(0, 0, 0))
    return tile


def _title(row: dict[str, Any]) -> str:
    if "exact_share" not in row:
        return row.get("name", row.get("label", "?"))
    return f"{row['name']}: {100 * row['exact_share']:.1f}% exact, max err {row['max_error']}"


def compose_all(data: dict[str, Any], out_dir: Path, tiles: dict) -> list[Path]:
    """One PNG per picture figure measured in this run: its variants side by side."""
    written = []
    plan = data.get("plan", {})
    width, height = plan.get("image_width", 160), plan.get("image_height", 100)
    for number in VARIANTS:
        rows = data.get(f"figure_{number.replace('.', '_')}") or []
        if not any(key[0] == number for key in tiles):
            continue
        sheet = Image.new("RGB", (width * len(rows), height + HEADER_PX), (255, 255, 255))
        for i, row in enumerate(rows):
            sheet.paste(_tile(tiles.get((number, row.get("name"))), _title(row), width, height), (i * width, 0))
        path = Path(out_dir) / figure_file(number)
        sheet.save(path, optimize=True)
        if path.stat().st_size > MAX_PNG_BYTES:  # a palette keeps the picture and a report small
            sheet.quantize(256).save(path, optimize=True)
        written.append(path)
    return written


__all__ = ["VARIANTS", "Variant", "compose_all", "render_variant"]
