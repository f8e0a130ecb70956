"""What one full recompute of a world costs, estimated from its configuration alone.

The unit is the *voxel visit*: one voxel reading one other voxel's value (or its own, in a
pass over the field). Every algorithm's cost is counted in it, as an upper bound:

- ``exact``: three separable passes, so 3 visits a voxel (6 in a Euclidean or signed world:
  the lower envelopes read each line twice).
- ``brute``: every voxel scans its window, ``min(W, 2·cap+1)`` voxels along each axis (``W``
  the world's side, or the chunk's with padded borders): the window's volume a voxel.
- ``fim``: relaxation passes of 7 reads each (the voxel and its 6 neighbours) until nothing
  changes. Distance travels at least one voxel a pass, so there are at most ``cap + 1``
  passes, and no more than the box's Manhattan diameter (the chunk's with padded borders).
- ``jfa`` (``jfa+1``, ``jfa+2``): 27 reads a pass (the voxel and its 26 neighbours), one pass
  for each halving step from ``min(side, cap)`` down to 1, plus the extra passes.
- ``jfa_fim``: jump flooding, then FIM passes to convergence; counted as jump flooding plus
  ``JFA_FIM_PASSES`` FIM passes.
- ``conservative``: one read pass, coarse sweeps and one write pass: 3 visits a voxel.

A world with a focus runs its algorithm on the focus and ``lod_algorithm`` on the rest. A
sparse world recomputes dense scratch boxes of its stored bricks, each at most ``MAX_SIDE_VOX``
a side; its estimate counts at most that many voxels (``MAX_WORLD_VOXELS``).

The server refuses a create, an import or a reconfiguration whose full recompute would pass
``Settings.max_recompute_voxel_visits`` (``RecomputeCostExceeded``, 422), before anything
changes; docs/configuration.md says how the default was chosen.
"""

from __future__ import annotations

from dataclasses import dataclass

from sdfserver.errors import RecomputeCostExceeded
from sdfserver.world_config import MAX_WORLD_VOXELS, WorldConfig

EXACT_VISITS = 3  # three separable passes
EXACT_EUCLIDEAN_VISITS = 6
FIM_VISITS_PER_PASS = 7  # the voxel and its 6 face neighbours
JFA_VISITS_PER_PASS = 27  # the voxel and its 26 neighbours at {-s, 0, s}^3
JFA_EXTRA_PASSES = {"jfa": 0, "jfa+1": 1, "jfa+2": 2}
JFA_FIM_PASSES = 8  # FIM passes counted after jump flooding, which leaves few to do
CONSERVATIVE_VISITS = 3
# 3e10 visits: about 50 ms of an H100 at the rates measured (docs/configuration.md); it admits
# the largest dense world (2048^3) with the default algorithm.
DEFAULT_MAX_VISITS = 30_000_000_000


@dataclass(frozen=True)
class RecomputeCost:
    """A full recompute's estimated work, and how it was counted (for messages)."""

    visits: int
    algorithm: str
    voxels: int
    visits_per_voxel: int

    def describe(self, config: WorldConfig) -> str:
        sx, sy, sz = config.size
        side = f"{sx}³" if sx == sy == sz else f"{sx}x{sy}x{sz}"
        what = "voxel pairs" if self.algorithm == "brute" else "voxel visits"
        padded = ", padded borders" if config.borders == "padded" else ""
        return (f"{self.algorithm} at {side}, cap {config.max_distance}{padded} would scan {_num(self.visits)} "
                f"{what} ({self.visits_per_voxel:,} a voxel)")


def _num(n: int) -> str:
    mantissa, _, exponent = f"{n:.2g}".partition("e")
    return f"{mantissa}e{int(exponent)}" if exponent else mantissa


def _jfa_passes(reach: int, cap: int, extra: int) -> int:
    n = min(reach, cap)
    return (max(n - 1, 0).bit_length() if n >= 2 else 0) + extra


def visits_per_voxel(algorithm: str, config: WorldConfig) -> int:
    """Voxel visits a voxel costs in one full recompute by ``algorithm`` (an upper bound)."""
    cap = config.max_distance
    padded = config.borders == "padded"
    sides = (config.chunk_size,) * 3 if padded else config.size
    if algorithm == "exact":
        return EXACT_EUCLIDEAN_VISITS if (config.euclidean or config.signed) else EXACT_VISITS
    if algorithm == "brute":
        out = 1
        for side in sides:
            out *= min(side, 2 * cap + 1)
        return out
    if algorithm == "fim":
        return FIM_VISITS_PER_PASS * min(cap + 1, sum(sides))
    if algorithm in JFA_EXTRA_PASSES:
        return JFA_VISITS_PER_PASS * max(_jfa_passes(max(sides), cap, JFA_EXTRA_PASSES[algorithm]), 1)
    if algorithm == "jfa_fim":
        return visits_per_voxel("jfa", config) + FIM_VISITS_PER_PASS * JFA_FIM_PASSES
    if algorithm == "conservative":
        return CONSERVATIVE_VISITS
    raise ValueError(f"no cost model for algorithm {algorithm!r}")


def _voxels(config: WorldConfig) -> tuple[int, int]:
    """(voxels the world's algorithm computes, voxels ``lod_algorithm`` computes)."""
    sx, sy, sz = config.size
    total = sx * sy * sz
    if config.storage == "sparse":
        return min(total, MAX_WORLD_VOXELS), 0
    if config.focus is None:
        return total, 0
    box = config.focus.chunk_box()
    inside = 1
    for lo, hi, n in zip(box.lo, box.hi, config.chunks):
        inside *= max(0, min(hi, n) - max(lo, 0)) * config.chunk_size
    return inside, total - inside


def estimate(config: WorldConfig) -> RecomputeCost:
    """The work of recomputing every voxel of a world of ``config`` (validated)."""
    inside, outside = _voxels(config)
    per_voxel = visits_per_voxel(config.algorithm, config)
    visits = inside * per_voxel
    if outside:
        visits += outside * visits_per_voxel(config.lod_algorithm, config)
    heavier = config.algorithm
    if outside and visits_per_voxel(config.lod_algorithm, config) > per_voxel:
        heavier, per_voxel = config.lod_algorithm, visits_per_voxel(config.lod_algorithm, config)
    return RecomputeCost(visits, heavier, inside + outside, per_voxel)


def check(config: WorldConfig, max_visits: int | None) -> None:
    """Raise RecomputeCostExceeded when a full recompute of ``config`` would pass ``max_visits``
    (None: no limit)."""
    if max_visits is None:
        return
    cost = estimate(config)
    if cost.visits > max_visits:
        raise RecomputeCostExceeded(
            f"{cost.describe(config)}; this server allows {_num(max_visits)} a recompute "
            f"(max_recompute_voxel_visits). Choose a smaller world or cap, or algorithm 'exact' "
            f"({visits_per_voxel('exact', config)} visits a voxel)")


__all__ = ["DEFAULT_MAX_VISITS", "RecomputeCost", "check", "estimate", "visits_per_voxel"]
