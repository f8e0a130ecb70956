"""Crews hunted for races on a real device: one-chunk worlds of the seed tables' kind (``populate``,
then three rounds of random brushes, each regenerated whole) under crews of several sizes, against
a launch a pass voxel for voxel and scipy's taxicab transform where the algorithm is exact. Every
lone box takes a crew here, on any device (production: GPUs only).

    PYTHONPATH=$PWD python3 tools/crew_check.py --device nvidia --worlds 25
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy import ndimage

from sdfserver.algorithms import ALGORITHMS, one_launch
from sdfserver.algorithms.fim import Fim
from sdfserver.algorithms.jfa import Jfa
from sdfserver.algorithms.jfa_fim import JfaFim
from sdfserver.bench.scene import populate, random_brushes
from sdfserver.gpu import GpuContext
from sdfserver.world import World, WorldConfig

MAKE = {"fim": lambda one: Fim(one_launch=one), "jfa": lambda one: Jfa(0, one_launch=one),
        "jfa_fim": lambda one: JfaFim(one_launch=one)}
CASES = (("jfa_fim", 16), ("jfa", 16), ("fim", 16), ("fim", 32), ("jfa_fim", 8))


def regenerations(gpu: GpuContext, algorithm: str, size: int, seed: int, crew: bool):
    ALGORITHMS[algorithm] = MAKE[algorithm](crew)
    world = World(gpu, WorldConfig((size,) * 3, size, 255, algorithm))
    try:
        populate(world, np.random.default_rng(seed), brushes_per_chunk=4)
        fields, launches = [], []
        for k in range(3):
            world.apply_edits(random_brushes(np.random.default_rng(seed * 7 + k), (size,) * 3, 2, size / 2))
            world.mark_all_dirty()
            launches.append(len(world.recompute().kernel_ms))
            fields.append(world.read_field())
        return fields, world.read_voxels(), launches
    finally:
        world.release()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None)
    p.add_argument("--worlds", type=int, default=25)
    p.add_argument("--per-group", default="64,256,512")
    args = p.parse_args()
    gpu = GpuContext.create(args.device)
    one_launch.takes_crews = lambda gpu: True
    one_launch.LONE_GROUP_VOXELS = {False: 0, True: 0}
    bad = checked = 0
    for per_group in (int(v) for v in args.per_group.split(",")):
        one_launch.CREW_VOXELS_PER_GROUP = {False: per_group, True: per_group}
        for algorithm, size in CASES:
            for seed in range(args.worlds):
                crew, voxels, launches = regenerations(gpu, algorithm, size, 1000 * per_group + seed, True)
                multi, _, _ = regenerations(gpu, algorithm, size, 1000 * per_group + seed, False)
                same = all(np.array_equal(a, b) for a, b in zip(crew, multi))
                exact = algorithm == "jfa" or np.array_equal(
                    (crew[-1] >> 8).astype(np.int64),
                    np.minimum(ndimage.distance_transform_cdt(voxels == 0, metric="taxicab"), 255))
                checked += 1
                if not (same and exact and launches == [1, 1, 1]):
                    bad += 1
                    print(f"MISMATCH crew/{per_group} {algorithm} {size}^3 world {seed}: equal to a launch a pass "
                          f"{same}, to the oracle {exact}, launches {launches}", flush=True)
            print(f"crew/{per_group} {algorithm} {size}^3: {args.worlds} worlds x 3 regenerations", flush=True)
    print(f"{checked} worlds, {bad} wrong")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
