"""Crews' shape against a launch a pass: the seed tables' one-chunk worlds (Tables 4.4-4.6, a full
regeneration after random brush edits, mean device ms of ``--reps``, as ``sdfserver bench seed``
times them), with a crew's group for each V voxels (``--per-group``) and a flood's chains of C
voxels (``--chains``), beside the tree's choice and a launch a pass:

    PYTHONPATH=$PWD python3 tools/crew_timing.py --device nvidia --json $OUT/crews.json
"""

from __future__ import annotations

import argparse
import itertools
import json

import numpy as np

from sdfserver.algorithms import ALGORITHMS, one_launch
from sdfserver.algorithms.fim import Fim
from sdfserver.algorithms.jfa import Jfa
from sdfserver.algorithms.jfa_fim import JfaFim
from sdfserver.bench.timing import measure_chunk
from sdfserver.gpu import GpuContext

BENCH_SEED = 2025  # sdfserver bench seed's default --seed; a table's world of side n is drawn from seed + n
MAKE = {"fim": lambda one: Fim(one_launch=one), "jfa": lambda one: Jfa(0, one_launch=one),
        "jfa_fim": lambda one: JfaFim(one_launch=one)}
CASES = (("jfa_fim", 16), ("jfa", 16), ("fim", 32))  # the lone boxes that crews take by default


def timed(gpu: GpuContext, algorithm: str, size: int, reps: int, mode: str, per_group: int | None = None,
          chain: int | None = None) -> dict:
    default_per_group, default_chain = dict(one_launch.CREW_VOXELS_PER_GROUP), one_launch.CREW_FLOOD_CHAIN
    ALGORITHMS[algorithm] = MAKE[algorithm](mode != "multi")
    if per_group:
        one_launch.CREW_VOXELS_PER_GROUP = dict.fromkeys(default_per_group, per_group)
    if chain:
        one_launch.CREW_FLOOD_CHAIN = chain
    try:
        row = measure_chunk(gpu, algorithm, size, reps, np.random.default_rng(BENCH_SEED + size))
    finally:
        one_launch.CREW_VOXELS_PER_GROUP, one_launch.CREW_FLOOD_CHAIN = default_per_group, default_chain
        ALGORITHMS[algorithm] = MAKE[algorithm](True)
    row = {"mode": mode, "per_group": per_group, "chain": chain, **row}
    print(f"{algorithm:8s} {size:3d}^3 {mode:24s} mean {row['mean_ms']:.4f} median {row['median_ms']:.4f} "
          f"min {row['min_ms']:.4f} ms  iterations {row['iterations_mean']:.2f}", flush=True)
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None)
    p.add_argument("--reps", type=int, default=20)
    p.add_argument("--per-group", default="256,512,1024,2048")
    p.add_argument("--chains", default="1,2,4")
    p.add_argument("--json", default=None)
    args = p.parse_args()
    gpu = GpuContext.create(args.device)
    per_groups = [int(v) for v in args.per_group.split(",") if v]
    chains = [int(c) for c in args.chains.split(",") if c]
    rows = []
    for algorithm, size in CASES:
        rows.append(timed(gpu, algorithm, size, args.reps, "as chosen"))
        rows.append(timed(gpu, algorithm, size, args.reps, "multi"))
        for per_group, chain in itertools.product(per_groups, chains if algorithm != "fim" else [None]):
            label = f"crew/{per_group}" + (f" chain {chain}" if chain else "")
            rows.append(timed(gpu, algorithm, size, args.reps, label, per_group, chain))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"device": gpu.device.name, "compute_units": gpu.device.max_compute_units, "rows": rows}, f,
                      indent=1)


if __name__ == "__main__":
    main()
