"""Per-pass timing of the exact transform on one world, across segment lengths.

    python tools/tune_exact.py --size 512 --segs 8,16,32 --reps 20

For each pass and SEG: the kernel's work-group limit, private (spilled) and
local memory, the median device time with passes launched back to back (no
host round trip between repetitions), and the achieved bandwidth.
"""

from __future__ import annotations

import argparse
import re

import numpy as np
import pyopencl as cl

from sdfserver.algorithms import RegionJob
from sdfserver.algorithms.exact import X_PASS_THREADS, Exact
from sdfserver.bench.scene import populate
from sdfserver.edits import EditLimits
from sdfserver.gpu import GpuContext
from sdfserver.world import World, WorldConfig


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--segs", default="0", help="SEG of every pass, or XSEG:YZSEG[:VEC], comma list (0: tuned)")
    p.add_argument("--order", default="012", help="pass order, axes as digits (x=0): e.g. 012 or 120; comma list")
    p.add_argument("--x-threads", default=str(X_PASS_THREADS), help="work-items per x-pass work-group, comma list")
    p.add_argument("--ptx16", type=int, choices=(0, 1), default=None,
                   help="force SDF_PTX_16X2 off (0) or on (1); default: what the device supports")
    p.add_argument("--lanes", default="0", help="x-lanes of the y/z passes, comma list of L or YL:ZL (0: tuned)")
    p.add_argument("--reps", type=int, default=20)
    p.add_argument("--check", type=int, choices=(0, 1), default=1,
                   help="compare each combination's field with the first recompute's (0: skip, for 2048^3)")
    p.add_argument("--device", default=None)
    p.add_argument("--define", action="append", default=[], metavar="NAME=VALUE",
                   help="extra -D for every build (experiments), repeatable")
    p.add_argument("--ptx", default=None, help="write each program's binary (PTX on NVIDIA) under this prefix")
    args = p.parse_args()
    gpu = GpuContext.create(args.device)
    if args.ptx16 is not None:
        gpu.programs.device_defines["SDF_PTX_16X2"] = args.ptx16
    for define in args.define:
        name, value = define.split("=", 1)
        gpu.programs.device_defines[name] = int(value)
    n = args.size
    world = World(gpu, WorldConfig((n, n, n), 32, 255), EditLimits(max_ops_per_batch=4096))
    populate(world, np.random.default_rng(1))
    world.recompute()
    reference = world.read_field() if args.check else None
    job = RegionJob.seeded_region(world.buffers, world.world_box, 255)
    exact = Exact()
    print(f"{gpu.device_name}, {n}^3, defines {gpu.programs.device_defines}")
    combos = [(s, l, int(t), o) for s in args.segs.split(",") for l in args.lanes.split(",")
              for t in args.x_threads.split(",") for o in args.order.split(",")]
    for spec, lanes, x_threads, order_spec in combos:
        parts = [int(v) for v in spec.split(":")]
        xseg, yzseg, vec = (parts + [parts[-1], 0][len(parts) - 1:])[:3]
        seg = xseg
        launches = []
        lanes_yz = [int(v) for v in lanes.split(":")] * 2
        if yzseg and max(lanes_yz) * -(-n // yzseg) > 1024:
            print(f"SEG={xseg}:{yzseg} vec={vec} lanes={lanes}: work-group over 1024, skipped")
            continue
        order = [int(c) for c in order_spec]
        # Bytes each pass must move: uchar in and out; the last writes the uint16 field instead
        # (its voxel reads, only where solids are, are not counted).
        bytes_moved = {axis: (3 if position == 2 else 2) * n**3 for position, axis in enumerate(order)}
        for position, axis in enumerate(order):
            kernel, nseg, global_, local = exact.launch_shape(gpu, axis, n, n, n, n, seg=(yzseg if axis else xseg) or None,
                                                                lanes=lanes_yz[axis - 1] if axis else None,
                                                                vec=vec or None,
                                                                x_threads=x_threads,
                                                                first=position == 0, last=position == 2)
            info = {k: kernel.get_work_group_info(getattr(cl.kernel_work_group_info, k), gpu.device)
                    for k in ("WORK_GROUP_SIZE", "PRIVATE_MEM_SIZE", "LOCAL_MEM_SIZE")}
            launches.append((axis, kernel, nseg, global_, local, info))
            if args.ptx and spec == args.segs.split(",")[0] and lanes == args.lanes.split(",")[0]:
                binary = kernel.program.get_info(cl.program_info.BINARIES)[0]
                with open(f"{args.ptx}-seg{seg}-axis{axis}.ptx", "wb") as f:
                    f.write(binary)
                text = binary.decode(errors="replace")
                info["ptx_local_decls"] = len(re.findall(r"\.local\s", text))
        def enqueue(kernel, global_, local):
            return exact.enqueue(gpu, job, kernel, global_, local)
        times = {0: [], 1: [], 2: []}
        for _ in range(2):  # warm-up
            for axis, kernel, nseg, g, l, _info in launches:
                enqueue(kernel, g, l)
        gpu.queue.finish()
        events = []
        for _ in range(args.reps):
            for axis, kernel, nseg, g, l, _info in launches:
                events.append((axis, enqueue(kernel, g, l)))
        gpu.queue.finish()
        for axis, e in events:
            times[axis].append((e.profile.end - e.profile.start) * 1e-6)
        ok = np.array_equal(world.read_field(), reference) if args.check else "not checked"
        total = sum(np.median(times[a]) for a in range(3))
        print(f"SEG={xseg}:{yzseg} vec={vec} lanes={lanes} x_threads={x_threads} order={order_spec} total {total:.4f} ms  correct={ok}")
        for axis, kernel, nseg, g, l, info in launches:
            t = np.median(times[axis])
            print(f"   pass {'xyz'[axis]}: {t:.4f} ms {bytes_moved[axis] / t / 1e9:.2f} TB/s  "
                  f"nseg={nseg} local={l} {info}")
    world.release()


if __name__ == "__main__":
    main()
