"""How the benchmarks time the device and summarize the samples.

Device times come from OpenCL profiling events (the sum of a recompute's kernel durations), so the
host's scheduling does not enter them; CuPy's anchors are timed by CUDA events the same way. A
summary carries the mean with its Student-t 95% interval (the dissertation's tables report those)
beside the median and minimum that the whole-world tables quote.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from sdfserver.bench.scene import populate, random_brushes
from sdfserver.edits import EditLimits
from sdfserver.world import World, WorldConfig


def summarize(samples_ms: list[float]) -> dict:
    a = np.asarray(samples_ms, dtype=np.float64)
    n = len(a)
    mean = float(a.mean())
    std = float(a.std(ddof=1)) if n > 1 else 0.0
    half = float(stats.t.ppf(0.975, n - 1) * std / math.sqrt(n)) if n > 1 else 0.0
    return {"n": n, "mean_ms": mean, "std_ms": std, "ci95_ms": [mean - half, mean + half],
            "median_ms": float(np.median(a)), "min_ms": float(a.min())}


def cupy_event_ms(call, reps: int) -> list[float]:
    """``reps`` timings of ``call()`` on the GPU by CuPy events (after one warm-up call), in ms."""
    import cupy

    call()
    times = []
    for _ in range(reps):
        start, end = cupy.cuda.Event(), cupy.cuda.Event()
        start.record()
        call()
        end.record()
        end.synchronize()
        times.append(cupy.cuda.get_elapsed_time(start, end))
    return times


def time_full(world: World, reps: int, rng: np.random.Generator | None = None):
    """Device times and iteration counts of `reps` full regenerations, and the last one's launches.
    With ``rng``, two fresh brushes before each, so an algorithm that converges starts afresh."""
    times, iterations, launches = [], [], []
    world.recompute()  # warm-up: builds the programs
    for _ in range(reps):
        if rng is not None:
            world.apply_edits(random_brushes(rng, world.config.size, 2, world.config.chunk_size / 2))
        world.mark_all_dirty()
        result = world.recompute()
        times.append(result.device_ms)
        iterations.append(result.iterations)
        launches = result.kernel_ms
    return times, iterations, launches


def measure_chunk(gpu, algorithm: str, cs: int, reps: int, rng: np.random.Generator, max_distance: int = 255,
                  limits: EditLimits = EditLimits(max_ops_per_batch=4096)) -> dict:
    """One world of one chunk: full regenerations after random brush edits (the dissertation's
    Tables 4.2, 4.4, 4.5, 4.6). Brute force above 32^3 takes a tenth of the repetitions, since
    each of its runs is O(n^6)."""
    world = World(gpu, WorldConfig((cs, cs, cs), cs, max_distance, algorithm), limits)
    try:
        populate(world, rng, brushes_per_chunk=4)
        reps = reps if algorithm != "brute" or cs <= 32 else max(2, reps // 10)
        times, iters, _ = time_full(world, reps, rng)
    finally:
        world.release()
    return {"algorithm": algorithm, "chunk_size": cs, **summarize(times), "iterations_mean": float(np.mean(iters))}
