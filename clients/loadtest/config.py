"""The run's settings and the brushes its game clients paint (random, from a seed)."""

from __future__ import annotations

import random
from dataclasses import dataclass, field

from sdfclient import edits


@dataclass(frozen=True)
class LoadConfig:
    url: str
    world_id: str = ""
    world_size: tuple[int, int, int] = (64, 64, 64)
    clients: int = 4
    duration_s: float = 10.0
    requests: int = 0  # 0: no count limit (the duration still bounds the run)
    rate: float = 0.0  # total requests per second; 0: as fast as possible
    read_every: int = 1  # read the field after every k-th edit; 0: never
    read_size: int = 16  # side of the box read around an edit; 0: the whole world
    read_format: str = "distance"
    ops_per_batch: int = 1
    brush_min: float = 1.0
    brush_max: float = 8.0
    delete_fraction: float = 0.25
    sphere_fraction: float = 0.5
    seed: int = 0
    timeout_s: float = 30.0
    edits_over: str = "http"  # http: POST /edits; ws: the WebSocket stream (reads stay HTTP)
    http: str = "httptools"  # httptools: loadtest.parsed.ParsedConnection; aiohttp: loadtest.connection; httpx: sdfclient.AsyncClient
    loop: str = "uvloop"  # the generator's event loop: uvloop (when installed) or asyncio
    api_key: str | None = field(default=None, repr=False)  # sent as a bearer token; never reported


# -- the brushes --------------------------------------------------------------------------------


class Brushes:
    """Random brush batches from one seeded generator."""

    def __init__(self, seed: int, cfg: LoadConfig):
        self.rng = random.Random(seed)
        self.cfg = cfg

    def batch(self) -> tuple[list[dict], tuple[int, int, int]]:
        ops, center = [], (0, 0, 0)
        for _ in range(self.cfg.ops_per_batch):
            op, center = self.brush()
            ops.append(op)
        return ops, center

    def brush(self) -> tuple[dict, tuple[int, int, int]]:
        rng, cfg = self.rng, self.cfg
        center = tuple(rng.randrange(s) for s in cfg.world_size)
        colour = 0 if rng.random() < cfg.delete_fraction else rng.randrange(1, 256)
        if rng.random() < cfg.sphere_fraction:
            return edits.sphere(center, rng.uniform(cfg.brush_min, cfg.brush_max), colour), center
        half = [max(1, round(rng.uniform(cfg.brush_min, cfg.brush_max))) for _ in range(3)]
        lo = [max(0, c - h) for c, h in zip(center, half)]
        hi = [min(s, c + h) for c, h, s in zip(center, half, cfg.world_size)]
        return edits.box(lo, hi, colour), center

    def read_box(self, center: tuple[int, int, int]):
        if self.cfg.read_size <= 0:
            return None
        side = self.cfg.read_size
        lo = [min(max(0, c - side // 2), max(0, s - side)) for c, s in zip(center, self.cfg.world_size)]
        return lo, [min(s, l + side) for l, s in zip(lo, self.cfg.world_size)]
