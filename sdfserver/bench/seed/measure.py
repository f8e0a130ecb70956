"""The runs behind every table and figure of chapter 4, measured into one results dict.

No matplotlib here: the measuring machine need not have it (``figures`` re-plots from the JSON).
Each measurement is bounded in time (a run's duration, a repetition count), recorded as it ends
(``run.Results`` rewrites results.json), and a configuration this build cannot make is
recorded as not available rather than ending the run.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from sdfserver.bench.run import Results, progress
from sdfserver.bench.schedule import EDIT_INTERVAL_MS
from sdfserver.bench.seed import images
from sdfserver.bench.seed.tables import TABLES, table_key
from sdfserver.bench.timing import measure_chunk
from sdfserver.errors import DeviceMemoryExceeded, InvalidInput
from sdfserver.gpu import GpuContext
from sdfserver.render.bench import NotAvailable, run_one
from sdfserver.render.renderer import Renderer
from sdfserver.world_config import padded_algorithms


@dataclass(frozen=True)
class Plan:
    """Sizes and bounds of one run; FULL uses the dissertation's sizes, QUICK tiny ones."""

    render_s: float  # seconds per render run of Tables 4.1 and 4.3
    grid_s: float  # seconds per render run of Figures 4.3, 4.6, 4.7, 4.8
    width: int
    height: int
    reps: int  # full regenerations per single-chunk row
    table_4_1_sizes: tuple[int, ...]
    table_4_3_sizes: tuple[int, ...]
    chunk_sizes: tuple[int, ...]  # Tables 4.2, 4.4, 4.5, 4.6
    grid_worlds: tuple[int, ...]  # Figures 4.3 and 4.6: world x chunk
    grid_chunks: tuple[int, ...]
    focus_world: int  # Figures 4.7 and 4.8
    focus_chunk: int
    focus_sizes: tuple[int, ...]  # chunks a side; the largest covers the world
    image_world: int  # Figures 4.5 and 4.9
    image_chunk: int
    image_width: int
    image_height: int
    image_brushes: int
    image_focus: tuple[int, ...]


FULL = Plan(render_s=5.0, grid_s=2.5, width=1280, height=720, reps=20,
            table_4_1_sizes=(8, 16, 32, 64, 128), table_4_3_sizes=(32, 64, 128, 256, 512),
            chunk_sizes=(8, 16, 32, 64, 128), grid_worlds=(64, 128, 256, 512), grid_chunks=(8, 16, 32, 64),
            focus_world=256, focus_chunk=16, focus_sizes=(1, 2, 4, 8, 16),
            image_world=128, image_chunk=16, image_width=480, image_height=300, image_brushes=60,
            image_focus=(1, 2, 8))
QUICK = Plan(render_s=0.5, grid_s=0.3, width=64, height=48, reps=3,
             table_4_1_sizes=(8, 16, 32), table_4_3_sizes=(32, 64),
             chunk_sizes=(8, 16), grid_worlds=(32, 64), grid_chunks=(8, 16),
             focus_world=64, focus_chunk=16, focus_sizes=(1, 2, 4),
             image_world=32, image_chunk=8, image_width=160, image_height=100, image_brushes=12,
             image_focus=(1, 2, 4))

FOCUS_ALGORITHM = "jfa_fim"  # inside the focus: JFA then FIM (the dissertation's Algorithm 7)
FOCUS_LOD = ("jfa", "conservative")  # outside: the dissertation's JFA, and the lower-bound field


@dataclass(frozen=True)
class Step:
    section: str  # the results key
    label: str
    run: Callable[[], dict[str, Any]]


def _guarded(step: Step) -> dict[str, Any]:
    """The step's row, or a row saying why it could not be measured."""
    try:
        return step.run()
    except NotAvailable as exc:
        return {"not_available": str(exc)}
    except (DeviceMemoryExceeded, InvalidInput) as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}


def _render_step(section: str, label: str, gpu, renderer, plan: Plan, seed: int, size: int, algorithm: str,
                 duration_s: float, key: dict, **world) -> Step:
    def run() -> dict[str, Any]:
        return run_one(gpu, renderer, size, algorithm, edit_interval_ms=EDIT_INTERVAL_MS, duration_s=duration_s,
                       seed=seed, width=plan.width, height=plan.height, progress=progress, **world)
    return Step(section, label, lambda: {**key, **run()})


def steps(gpu: GpuContext, renderer: Renderer, plan: Plan, seed: int, borders: str, tiles: dict) -> Iterator[Step]:
    """Every measurement, in the order of chapter 4."""
    for spec in TABLES:
        section = table_key(spec.number)
        for size in (plan.table_4_1_sizes if spec.number == "4.1" else
                     plan.table_4_3_sizes if spec.number == "4.3" else plan.chunk_sizes):
            key = {"size": size, "algorithm": spec.algorithm}
            label = f"Table {spec.number}: {spec.algorithm} {size}^3"
            if spec.number == "4.1":
                yield _render_step(section, label, gpu, renderer, plan, seed, size, "brute", plan.render_s, key,
                                   chunk_size=None)
            elif spec.number == "4.3":
                yield _render_step(section, label, gpu, renderer, plan, seed, size, "brute", plan.render_s, key,
                                   chunk_size=16, borders="padded")
            else:
                rng = np.random.default_rng(seed + size)
                yield Step(section, label, lambda a=spec.algorithm, s=size, r=rng, k=key:
                           {**k, **measure_chunk(gpu, a, s, plan.reps, r)})
    for number, algorithm in (("4.3", "fim"), ("4.6", "jfa")):
        for world in plan.grid_worlds:
            for chunk in plan.grid_chunks:
                if chunk <= world:
                    yield _render_step(f"figure_{number.replace('.', '_')}",
                                       f"Figure {number}: {algorithm} {world}^3 in {chunk}^3 chunks",
                                       gpu, renderer, plan, seed, world, algorithm, plan.grid_s,
                                       {"size": world, "chunk": chunk, "algorithm": algorithm, "borders": borders},
                                       chunk_size=chunk, borders=borders)
    for lod in FOCUS_LOD:
        # Padded borders only where both of the world's algorithms have them (world_config says which).
        focus_borders = borders if {FOCUS_ALGORITHM, lod} <= set(padded_algorithms()) else "exact"
        for focus in plan.focus_sizes:
            yield _render_step("focus_sweep", f"Figures 4.7/4.8: focus {focus}, {lod} outside",
                               gpu, renderer, plan, seed, plan.focus_world, FOCUS_ALGORITHM, plan.grid_s,
                               {"size": plan.focus_world, "chunk": plan.focus_chunk, "focus": focus, "lod": lod,
                                "borders": focus_borders},
                               chunk_size=plan.focus_chunk, borders=focus_borders, focus=focus, lod_algorithm=lod)
    for number in ("4.5", "4.9"):
        for variant in images.VARIANTS[number](plan):
            yield Step(f"figure_{number.replace('.', '_')}", f"Figure {number}: {variant.name}",
                       lambda v=variant: images.render_variant(gpu, renderer, plan, seed, v, tiles))


def measure(gpu: GpuContext, plan: Plan, seed: int, borders: str, results: Results,
            out_dir, only: set[str] | None = None) -> None:
    """Runs every step (those of ``only``'s sections, if given), recording each as it ends, then
    composes the rendered images. A stop (KeyboardInterrupt) leaves the rows recorded so far."""
    results.data["plan"] = asdict(plan)
    renderer = Renderer(gpu)
    tiles: dict = {}
    try:
        todo = [s for s in steps(gpu, renderer, plan, seed, borders, tiles) if only is None or s.section in only]
        for i, step in enumerate(todo, 1):
            progress(f"[{i}/{len(todo)}] {bar(i - 1, len(todo))} {step.label}")
            row = _guarded(step)
            row.setdefault("label", step.label)
            results.add(step.section, row, f"{step.label}: {summary(row)}")
    finally:
        renderer.release()
        images.compose_all(results.data, out_dir, tiles)


def bar(done: int, total: int, width: int = 24) -> str:
    filled = round(width * done / max(1, total))
    return "[" + "#" * filled + "." * (width - filled) + "]"


def summary(row: dict[str, Any]) -> str:
    if "not_available" in row:
        return f"not available ({row['not_available']})"
    if "error" in row:
        return row["error"]
    if "fps" in row:
        return (f"{row['fps']['mean']:.1f} FPS, {row['fps_recompute']['mean']:.1f} FPS during recompute, "
                f"field {row['field_device_ms']['mean']:.3f} ms")
    if "mean_ms" in row:
        return f"mean {row['mean_ms']:.4f} ms over {row['n']}, {row['iterations_mean']:.2f} iterations"
    if "exact_share" in row:
        return f"{100 * row['exact_share']:.1f}% of voxels exact, max error {row['max_error']}"
    return "done"


__all__ = ["FULL", "QUICK", "Plan", "Step", "measure", "steps"]
