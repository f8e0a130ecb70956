"""Small boxes in one launch against a launch a pass: the seed tables' one-chunk worlds (Tables
4.4–4.6: a full regeneration after random brush edits, mean device ms of ``--reps``, as
``sdfserver bench seed`` times them), for fim, jfa and jfa_fim as the tree chooses (``default``),
forced into one work-group at every size that fits (``one``) and a launch a pass (``multi``); a
padded world (many groups in one launch); and the one-launch kernels' work-group limits, local
memory and, on NVIDIA, ptxas's register counts, beside a one-line kernel's limit. It imports
whichever sdfserver is first on the path, so one process per checkout compares two trees:

    PYTHONPATH=$PWD python3 tools/one_launch_timing.py --device nvidia --json $OUT/new.json
    (cd ab/base && PYTHONPATH=$PWD python3 ../../tools/one_launch_timing.py --device nvidia --json $OUT/base.json)

``--registers driver,64,32`` builds the limits' kernels also with NVIDIA's register caps
(``-cl-nv-maxrregcount``); ``--items 512,1024`` times one launch with that many work-items a group
whatever the kernel's reported limit (modes ``one@N``, and the padded world's ``@N``).
"""

from __future__ import annotations

import argparse
import contextlib
import json

import numpy as np
import pyopencl as cl

from sdfserver.algorithms import ALGORITHMS, one_launch
from sdfserver.algorithms.fim import Fim
from sdfserver.algorithms.jfa import Jfa
from sdfserver.algorithms.jfa_fim import JfaFim
from sdfserver.bench.timing import measure_chunk, summarize, time_full
from sdfserver.bench.scene import populate
from sdfserver.gpu import GpuContext
from sdfserver.gpu.programs import INCLUDE_DIR, KERNEL_DIR
from sdfserver.world import World, WorldConfig

BENCH_SEED = 2025  # sdfserver bench seed's default --seed; a table's world of side n is drawn from seed + n
MAKE = {"fim": lambda one: Fim(one_launch=one), "jfa": lambda one: Jfa(0, one_launch=one),
        "jfa_fim": lambda one: JfaFim(one_launch=one)}


ONE_LINE_KERNEL = "__kernel void one_line(__global int *a) { a[get_global_id(0)] += 1; }"


def kernel_info(gpu: GpuContext, registers: list[str]) -> list[dict]:
    """Each one-launch variant's limits (and a one-line kernel's), built again here with NVIDIA's
    verbose flag where it is accepted (ptxas prints the registers a work-item takes), once for each
    register cap (``driver``: none)."""
    rows = []
    source = (KERNEL_DIR / "one_launch.cl").read_text()
    device_defines = [f"-D{k}={v}" for k, v in gpu.programs.device_defines.items()]
    variants = [("one_line", ONE_LINE_KERNEL, [], {})]
    for flood, relax, weighted in ((False, True, 0), (True, False, 0), (True, False, 1), (True, True, 0),
                                   (True, True, 1)):
        defines = [f"-DONE_LAUNCH_FLOOD={int(flood)}", f"-DONE_LAUNCH_RELAX={int(relax)}",
                   f"-DONE_LAUNCH_WEIGHTED={weighted}", *device_defines]
        variants.append(("one_launch", source, defines, {"flood": flood, "relax": relax, "weighted": weighted}))
    for cap in registers:
        cap_options = [] if cap == "driver" else [f"-cl-nv-maxrregcount={int(cap)}"]
        for name, text, defines, key in variants:
            row = {"kernel": name, **key, "registers": cap}
            for extra in (["-cl-nv-verbose"], []):
                try:
                    program = cl.Program(gpu.context, text).build([f"-I{INCLUDE_DIR}", *defines, *cap_options, *extra])
                except Exception as error:  # noqa: BLE001 - a runtime that refuses the flag: built again without it
                    row["error"] = str(error)[:300]
                    continue
                kernel, device = cl.Kernel(program, name), gpu.device
                info = cl.kernel_work_group_info
                row.update(work_group_size=kernel.get_work_group_info(info.WORK_GROUP_SIZE, device),
                           local_mem=kernel.get_work_group_info(info.LOCAL_MEM_SIZE, device),
                           private_mem=kernel.get_work_group_info(info.PRIVATE_MEM_SIZE, device),
                           log=program.get_build_info(device, cl.program_build_info.LOG).strip()[-600:])
                row.pop("error", None)
                break
            rows.append(row)
    return rows


@contextlib.contextmanager
def group_items(items: int | None):
    """One-launch groups of ``items`` work-items (None: the kernel's reported limit, as the tree does)."""
    reported = one_launch.OneLaunch._limits

    def forced(self, gpu, weighted=True, crew=False):
        return items, reported(self, gpu, weighted, crew)[1]

    one_launch._STATES.clear()
    if items is not None:
        one_launch.OneLaunch._limits = forced
    try:
        yield
    finally:
        one_launch.OneLaunch._limits = reported
        one_launch._STATES.clear()


def chunk_rows(gpu: GpuContext, sizes: list[int], reps: int, chains: list[int], items: list[int]) -> list[dict]:
    """``one:C``: one launch with FLOOD_CHAIN=C (jump flooding's voxels a work-item takes);
    ``one@N``: one launch of N work-items a group (crews' shapes: tools/crew_timing.py)."""
    rows = []
    lone = dict(one_launch.LONE_GROUP_VOXELS)
    for algorithm, make in MAKE.items():
        for size in sizes:
            modes = (["default", "one", "multi"] + [f"one:{c}" for c in chains if algorithm != "fim"]
                     + [f"one@{n}" for n in items])
            for mode in modes:
                ALGORITHMS[algorithm] = make(mode != "multi")
                if ":" in mode:
                    ALGORITHMS[algorithm].small.defines["FLOOD_CHAIN"] = int(mode.split(":")[1])
                one_launch._STATES.clear()  # the limits of another variant
                one_launch.LONE_GROUP_VOXELS = (dict.fromkeys(lone, one_launch.MAX_BOX_VOXELS) if mode.startswith("one")
                                                else dict(lone))
                try:
                    with group_items(int(mode.split("@")[1]) if "@" in mode else None):
                        row = measure_chunk(gpu, algorithm, size, reps, np.random.default_rng(BENCH_SEED + size))
                finally:
                    one_launch.LONE_GROUP_VOXELS = dict(lone)
                rows.append({"mode": mode, **row})
                print(f"{algorithm:8s} {size:3d}^3 {mode:8s} mean {row['mean_ms']:.4f} median {row['median_ms']:.4f} "
                      f"min {row['min_ms']:.4f} ms  iterations {row['iterations_mean']:.2f}", flush=True)
        ALGORITHMS[algorithm] = make(True)
    return rows


def padded_rows(gpu: GpuContext, size: int, chunk: int, reps: int, items: list[int]) -> list[dict]:
    rows = []
    for algorithm in ("jfa", "jfa_fim"):
        for n in [None, *items]:
            world = World(gpu, WorldConfig((size,) * 3, chunk, 255, algorithm, borders="padded"))
            try:
                with group_items(n):
                    populate(world, np.random.default_rng(BENCH_SEED + size), brushes_per_chunk=4)
                    times, _, launches = time_full(world, reps, np.random.default_rng(BENCH_SEED))
            finally:
                world.release()
            row = {"algorithm": algorithm, "size": size, "chunk": chunk, "items": n, "launches": len(launches),
                   **summarize(times)}
            rows.append(row)
            print(f"padded {algorithm:8s} {size}^3 in {chunk}^3{f' @{n}' if n else ''}: mean {row['mean_ms']:.4f} "
                  f"median {row['median_ms']:.4f} ms, {row['launches']} launches", flush=True)
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None)
    p.add_argument("--sizes", default="8,16,32")
    p.add_argument("--reps", type=int, default=20)
    p.add_argument("--padded", default="128,16", help="world side, chunk side ('' for none)")
    p.add_argument("--chains", default="", help="FLOOD_CHAIN values to try in one launch (this tree's kernel)")
    p.add_argument("--registers", default="driver",
                   help="register caps to build the limits' kernels with (NVIDIA), e.g. driver,64,32")
    p.add_argument("--items", default="", help="work-items a group to force one launch to, e.g. 512,1024")
    p.add_argument("--json", default=None)
    args = p.parse_args()
    gpu = GpuContext.create(args.device)
    items = [int(n) for n in args.items.split(",") if n]
    info = kernel_info(gpu, args.registers.split(","))
    for row in info:
        print({k: v for k, v in row.items() if k != "log"})
        if "registers" in row.get("log", ""):
            print("   ", " | ".join(line.strip() for line in row["log"].splitlines() if "registers" in line or "spill" in line))
    out = {"device": gpu.device.name, "lone_group_voxels": {str(k): v for k, v in one_launch.LONE_GROUP_VOXELS.items()},
           "kernels": info, "chunks": chunk_rows(gpu, [int(s) for s in args.sizes.split(",")], args.reps,
                               [int(c) for c in args.chains.split(",") if c], items)}
    if args.padded:
        size, chunk = (int(v) for v in args.padded.split(","))
        out["padded"] = padded_rows(gpu, size, chunk, args.reps, items)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
