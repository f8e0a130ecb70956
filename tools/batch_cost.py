"""One edit batch of many large boxes through an Engine without HTTP: how long its step holds the
engine, phase by phase (docs/benchmarks.md, "One batch of many whole-world boxes").

    PYTHONPATH=. python tools/batch_cost.py --boxes 1024 [--shifted] [--side 128]

``--shifted``: boxes that no later box covers whole (64 x 112 x side, shifted along x and y),
which dropping hidden brushes cannot help; otherwise every box covers the whole world.
"""

from __future__ import annotations

import argparse
import time

from sdfserver.edits import parse_edits
from sdfserver.engine import Engine, EngineLimits
from sdfserver.engine.commands import ApplyEdits, CreateWorld
from sdfserver.gpu import GpuContext
from sdfserver.world import WorldConfig


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--boxes", type=int, default=1024)
    p.add_argument("--side", type=int, default=128)
    p.add_argument("--shifted", action="store_true")
    p.add_argument("--device", default=None)
    args = p.parse_args()
    n, side = args.boxes, args.side
    gpu = GpuContext.create(args.device, None)
    engine = Engine(gpu, EngineLimits())
    created = engine.submit(CreateWorld(WorldConfig(size=(side,) * 3)))
    engine.step()
    world_id = created.result()["id"]
    warm = [{"op": "box", "min": [0, 0, 0], "max": [1, 1, 1], "colour": 1}]
    engine.submit(ApplyEdits(world_id, parse_edits(warm), warm))
    engine.step()  # the brush and exact kernels built
    if args.shifted:
        raw = [{"op": "box", "min": [i % 64, (i // 64) % 16, 0], "max": [i % 64 + 64, (i // 64) % 16 + 112, side],
                "colour": 1 + i % 255} for i in range(n)]
    else:
        raw = [{"op": "box", "min": [0, 0, 0], "max": [side] * 3, "colour": 1 + i % 255} for i in range(n)]
    started = time.perf_counter()
    future = engine.submit(ApplyEdits(world_id, parse_edits(raw), raw))
    report = engine.step()
    ms = (time.perf_counter() - started) * 1e3
    outcome = future.exception() or f"version {future.result()}"
    print(f"{gpu.device_name}: {n} {'shifted' if args.shifted else 'whole-world'} boxes on {side}^3: step {ms:.1f} ms "
          f"{ {k: round(v, 1) for k, v in report.phases_ms.items()} }: {outcome}")


if __name__ == "__main__":
    main()
