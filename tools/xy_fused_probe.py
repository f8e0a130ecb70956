"""Feasibility probe: the exact transform's pass_x + y pass (sdfserver, kernels/exact.cl) against
a bits pass + one fused x+y pass (kernels/xy_fused_probe.cl). Checks that both write the same uint8
scratch byte for byte (and that it is the 2-D taxicab transform of each z plane, capped, by
scipy where installed, else numpy), then times each kernel with profiling events.

Run from the repository root:  python3 tools/xy_fused_probe.py --device NVIDIA --sizes 256,512,1024 --big
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pyopencl as cl

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # the repository root, for sdfserver

from sdfserver.algorithms.base import WORK_PLANE_PAD, RegionJob, WorldBuffers  # noqa: E402
from sdfserver.algorithms.exact import Exact, pass_args  # noqa: E402
from sdfserver.geometry import Box  # noqa: E402
from sdfserver.gpu import GpuContext  # noqa: E402

GROUP = 256
BANKS = 32


# ---------------------------------------------------------------- worlds

def sphere_world(shape_zyx, rng, solid=0.05, max_radius=8):
    """Small solid spheres (radius 1..max_radius) at random until ~`solid` of the voxels are solid,
    colours 1..255 (like the bench scene: many small brushes)."""
    nz, ny, nx = shape_zyx
    v = np.zeros(shape_zyx, np.uint8)
    total = v.size
    balls = {}
    for r in range(1, max_radius + 1):
        g = np.arange(-r, r + 1)
        zz, yy, xx = np.meshgrid(g, g, g, indexing="ij")
        inside = zz ** 2 + yy ** 2 + xx ** 2 <= r * r + r  # a round-ish ball
        balls[r] = np.stack([zz[inside], yy[inside], xx[inside]], 1).astype(np.int64)
    flat = v.reshape(-1)
    mean_volume = np.mean([len(b) for b in balls.values()])
    while np.count_nonzero(flat) < solid * total:
        left = solid * total - np.count_nonzero(flat)
        count = max(1, int(left / mean_volume / 2))  # about half of what is left (balls overlap, clip)
        centres = (rng.random((count, 3)) * np.array([nz, ny, nx])).astype(np.int64)
        radii = rng.integers(1, max_radius + 1, count)
        colours = rng.integers(1, 256, count).astype(np.uint8)
        for r, ball in balls.items():
            pick = radii == r
            if not pick.any():
                continue
            p = centres[pick][:, None, :] + ball[None]  # (k, m, 3)
            c = np.broadcast_to(colours[pick][:, None], p.shape[:2])
            ok = ((p >= 0) & (p < np.array([nz, ny, nx]))).all(-1)
            p, c = p[ok], c[ok]
            flat[(p[:, 0] * ny + p[:, 1]) * nx + p[:, 2]] = c
    return v


def random_world(shape_zyx, rng, solid=0.30):
    v = np.empty(shape_zyx, np.uint8)
    for z in range(shape_zyx[0]):  # plane by plane: a 1024^3 world in float64 would be 8 GB
        r = rng.random(shape_zyx[1:])
        v[z] = np.where(r < solid, rng.integers(1, 256, shape_zyx[1:]), 0)
    return v


def worlds(shape_zyx, seed=1):
    rng = np.random.default_rng(seed)
    yield "spheres", sphere_world(shape_zyx, rng)
    yield "empty", np.zeros(shape_zyx, np.uint8)
    yield "random30", random_world(shape_zyx, rng)
    yield "sparse", random_world(shape_zyx, rng, 0.002)  # long halos (not in the default --worlds)


# ---------------------------------------------------------------- reference

def reference_plane(solid2d, cap):
    """2-D taxicab distance to the nearest solid of one plane, capped."""
    try:
        from scipy.ndimage import distance_transform_cdt
    except ImportError:
        distance_transform_cdt = None
    if not solid2d.any():
        return np.full(solid2d.shape, cap, np.uint8)
    if distance_transform_cdt is not None:
        d = distance_transform_cdt(~solid2d, metric="taxicab").astype(np.int64)
    else:  # separable min-plus, numpy
        ny, nx = solid2d.shape
        d = np.where(solid2d, 0, 1 << 20).astype(np.int64)
        for axis, n in ((1, nx), (0, ny)):
            d = np.moveaxis(d, axis, 0).copy()
            for i in range(1, n):
                d[i] = np.minimum(d[i], d[i - 1] + 1)
            for i in range(n - 2, -1, -1):
                d[i] = np.minimum(d[i], d[i + 1] + 1)
            d = np.moveaxis(d, 0, axis)
    return np.minimum(d, cap).astype(np.uint8)


# ---------------------------------------------------------------- new kernels' shapes

def bank_degree(words):
    """Wavefronts one warp's 32-bit local access takes: the most distinct words in one bank."""
    per_bank = {}
    for w in words:
        per_bank.setdefault(w % BANKS, set()).add(w)
    return max(len(s) for s in per_bank.values())


def fused_shape(nx, ny, cap, tx=None, phase3=0):
    if nx % 8:
        raise ValueError("nx must be a multiple of 8")
    if tx is None:
        tx = 64 if ny <= 512 else 32
    lanes = tx // 2
    nseg = GROUP // lanes
    seg = -(-ny // nseg)
    syt = seg * nseg
    if syt % 2 or syt * tx > 32768 or tx % 32:
        raise ValueError(f"unsupported: ny={ny} with tx={tx} (tx a multiple of 32, tx * ny <= 32 KiB)")
    half = syt // 2

    def row(y, rsw, spad):
        return y * rsw + (y // seg) * spad

    best = None
    for rsw in range(tx // 4, tx // 4 + 8):
        for spad in range(0, 32):
            p1 = max(bank_degree([row(y, rsw, spad) for y in range(w, min(w + 32, half))])
                     for w in range(0, half, 32))
            p2 = 0
            for w in range(0, GROUP, 32):
                for k in sorted({0, 1, seg - 1}):
                    p2 = max(p2, bank_degree([(2 * row((lid // lanes) * seg + k, rsw, spad) + lid % lanes) // 2
                                              for lid in range(w, w + 32)]))
            words = row(syt - 1, rsw, spad) + tx // 4
            cost = (p1 + p2, words)
            if best is None or cost < best[0]:
                best = (cost, rsw, spad, p1, p2)
        if best[3] == 1 and best[4] == 1:
            break
    (_, words), rsw, spad, p1, p2 = best
    tile_words = max(words, 4 * nseg * lanes)
    return dict(TX=tx, SYT=syt, SEG=seg, NSEG=nseg, LANES=lanes, RSW=rsw, SPAD=spad,
                HW=-(-cap // 32), TILE_WORDS=tile_words, PHASE3=phase3), (p1, p2)


def bits_launch(nx, rows):
    nw = -(-nx // 32)
    nh = 2 * nw
    lx = 1
    while lx < nh and lx < 64:
        lx *= 2
    ly = GROUP // lx
    return nw, nh, (-(-nh // lx) * lx, -(-rows // ly) * ly), (lx, ly)


# ---------------------------------------------------------------- the probe

class Probe:
    def __init__(self, gpu: GpuContext):
        self.gpu = gpu
        self.ctx, self.queue = gpu.context, gpu.queue
        self.src = (HERE.parent / "kernels" / "xy_fused_probe.cl").read_text()
        self.defines = dict(gpu.programs.device_defines)
        self.exact = Exact()
        self._programs = {}

    def program(self, **defines):
        key = tuple(sorted(defines.items()))
        if key not in self._programs:
            opts = [f"-D{k}={v}" for k, v in {**self.defines, **defines}.items()]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", cl.CompilerWarning)
                self._programs[key] = cl.Program(self.ctx, self.src).build(options=opts)
        return self._programs[key]

    def setup(self, vox, cap, tx=None):
        nz, ny, nx = vox.shape
        mf = cl.mem_flags
        plane = nx * ny + WORK_PLANE_PAD
        self.shape, self.cap, self.plane = (nx, ny, nz), cap, plane
        b = self.buffers = dict(
            voxels=cl.Buffer(self.ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=vox),
            field=cl.Buffer(self.ctx, mf.READ_WRITE, 2 * vox.size),
            work=cl.Buffer(self.ctx, mf.READ_WRITE, plane * nz),
            work2=cl.Buffer(self.ctx, mf.READ_WRITE, plane * nz),
        )
        # old: sdfserver's own passes over the whole world (no seed shell, R = W = the world)
        wb = WorldBuffers((nx, ny, nz), b["voxels"], b["field"], b["work"], b["work2"])
        whole = Box.of_size((nx, ny, nz))
        self.job = RegionJob(wb, whole, whole, False, cap)
        self.old = self.exact.passes(self.gpu, (nx, ny, nz))[:2]
        self.old_args = pass_args(self.job)
        # new
        nw, nh, bglobal, blocal = bits_launch(nx, ny * nz)
        b["bits"] = cl.Buffer(self.ctx, mf.READ_WRITE, 4 * nw * ny * nz)
        self.nw = nw
        self.bits_k = cl.Kernel(self.program(), "bits_pass")
        self.bits_k.set_args(b["voxels"], b["bits"], np.int32(nx), np.int32(nh), np.int32(ny * nz))
        self.bits_launch = (bglobal, blocal)
        self.fused = {}  # label -> (kernel, global, local, defines, bank ways)
        for label, tx_v, phase3 in self.variants(ny, tx):
            defs, conflicts = fused_shape(nx, ny, cap, tx_v, phase3)
            k = cl.Kernel(self.program(**defs), "fused_xy")
            k.set_args(b["bits"], b["work2"], np.int32(nx), np.int32(ny), np.int32(nw), np.int32(plane),
                       np.int32(cap))
            tiles = -(-nx // defs["TX"])
            self.fused[label] = (k, (tiles * GROUP, nz), (GROUP, 1), defs, conflicts)

    @staticmethod
    def variants(ny, tx):
        """The fused pass's variants: the main one first (default or --tx tile, direct writes), then
        the same with phase 3 (rows written from the tile), then the other tile width where it fits."""
        main = tx or (64 if ny <= 512 else 32)
        out = [("fused", main, 0), ("fused_p3", main, 1)]
        other = 32 if main == 64 else 64
        if other * (-(-ny // (GROUP // (other // 2))) * (GROUP // (other // 2))) <= 32768:
            out.append((f"fused_tx{other}", other, 0))
        return out

    def release(self):
        for buf in self.buffers.values():
            buf.release()

    def run_old(self):
        return [kernel(self.queue, global_, local, *self.old_args) for kernel, _, global_, local in self.old]

    def run_bits(self):
        return cl.enqueue_nd_range_kernel(self.queue, self.bits_k, *self.bits_launch)

    def run_fused(self, label="fused"):
        k, g, l, *_ = self.fused[label]
        return cl.enqueue_nd_range_kernel(self.queue, k, g, l)

    def scratch(self, name):
        nx, ny, nz = self.shape
        out = np.empty(self.plane * nz, np.uint8)
        cl.enqueue_copy(self.queue, out, self.buffers[name], is_blocking=True)
        return out.reshape(nz, self.plane)[:, :nx * ny].reshape(nz, ny, nx)

    def clear(self, name, value=0xEE):
        cl.enqueue_fill_buffer(self.queue, self.buffers[name], np.uint8(value), 0, self.plane * self.shape[2])
        self.queue.finish()


def ms(event):
    return (event.profile.end - event.profile.start) * 1e-6


def check(probe: Probe, vox, cap, ref_planes):
    """The new scratch against the old, and a few planes (all, when small) against the reference."""
    probe.clear("work")
    probe.run_old()
    old = probe.scratch("work")
    results = {}
    for label in probe.fused:
        probe.clear("work2")
        probe.run_bits()
        probe.run_fused(label)
        new = probe.scratch("work2")
        diff = int(np.count_nonzero(old != new))
        results[label] = diff
        if diff:
            z, y, x = np.argwhere(old != new)[0]
            print(f"    MISMATCH {label}: {diff} bytes differ; first at x={x} y={y} z={z}: "
                  f"old {old[z, y, x]} new {new[z, y, x]}")
    nz = vox.shape[0]
    planes = range(nz) if ref_planes >= nz else sorted({0, nz // 2, nz - 1, *range(0, nz, max(1, nz // ref_planes))})
    ref_bad = 0
    for z in planes:
        ref = reference_plane(vox[z] != 0, cap)
        ref_bad += int(np.count_nonzero(ref != old[z]))
    return results, ref_bad, len(planes)


def timed(probe: Probe, reps):
    labels = list(probe.fused)
    for _ in range(3):
        probe.run_old(); probe.run_bits()
        for label in labels:
            probe.run_fused(label)
    probe.queue.finish()
    runs = []
    for _ in range(reps):
        x, y = probe.run_old()
        b = probe.run_bits()
        runs.append((x, y, b, [probe.run_fused(label) for label in labels]))
    probe.queue.finish()
    t = [dict(x=ms(x), y=ms(y), bits=ms(b), **{label: ms(e) for label, e in zip(labels, f)}) for x, y, b, f in runs]
    for r in t:
        r["old"] = r["x"] + r["y"]
        r["new"] = r["bits"] + r["fused"]
    return {k: (statistics.median(r[k] for r in t), max(r[k] for r in t)) for k in t[0]}


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--device", default="", help="substring of '<platform> / <device>' (sdfserver's spec)")
    ap.add_argument("--sizes", default="64,128", help="cube sides, or XxYxZ shapes (x a multiple of 8)")
    ap.add_argument("--big", action="store_true", help="also 1024^3")
    ap.add_argument("--cap", type=int, default=255)
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--tx", type=int, default=None, help="fused tile width (32 or 64; default by ny)")
    ap.add_argument("--ref-planes", type=int, default=4, help="planes checked against the reference "
                    "(every plane when the world has no more)")
    ap.add_argument("--worlds", default="spheres,empty,random30")
    ap.add_argument("--no-time", action="store_true")
    args = ap.parse_args()

    gpu = GpuContext.create(args.device)
    print(f"device: {gpu.device_name}")
    probe = Probe(gpu)
    shapes = []
    for s in args.sizes.split(","):
        s = s.strip()
        shapes.append(tuple(int(v) for v in s.split("x")) if "x" in s else (int(s),) * 3)
    if args.big and (1024, 1024, 1024) not in shapes:
        shapes.append((1024, 1024, 1024))
    wanted = set(args.worlds.split(","))
    table, all_ok = [], True
    for nx, ny, nz in shapes:
        t0 = time.time()
        for name, vox in worlds((nz, ny, nx)):
            if name not in wanted:
                continue
            probe.setup(vox, args.cap, args.tx)
            defs, conflicts = probe.fused["fused"][3:]
            diffs, ref_bad, nref = check(probe, vox, args.cap, args.ref_planes)
            ok = not any(diffs.values()) and not ref_bad
            all_ok &= ok
            print(f"{nx}x{ny}x{nz} {name:9s} solid {np.count_nonzero(vox) / vox.size:6.2%}: new==old "
                  f"{'OK' if not any(diffs.values()) else 'FAIL ' + str(diffs)} ({', '.join(diffs)}); "
                  f"old vs reference on {nref} planes: {'OK' if not ref_bad else f'FAIL ({ref_bad} bytes)'}; "
                  f"main tile TX={defs['TX']} SYT={defs['SYT']} SEG={defs['SEG']}x{defs['NSEG']} "
                  f"RSW={defs['RSW']} SPAD={defs['SPAD']} local {4 * defs['TILE_WORDS']} B, "
                  f"bank ways p1/p2 {conflicts} [{time.time() - t0:.1f}s]")
            if not args.no_time:
                table.append(((nx, ny, nz), name, timed(probe, args.reps)))
            probe.release()
    if table:
        print(f"\ntimes in ms, median (max) of {args.reps} after 3 warm-ups. new = bits + fused (main variant: "
              f"default tile, direct writes); fused_p3: phase 3 writes rows from the tile; fused_txN: the other "
              f"tile width.\nGB/s from the minimal traffic: old x+y 4 B/voxel, bits 1.125, fused 1.125, new 2.25")
        extra = sorted({k for _, _, t in table for k in t} - {"x", "y", "old", "bits", "fused", "new"})
        cols = ["x", "y", "old", "bits", "fused", "new", *extra]
        names = dict(x="old x", y="old y", old="old x+y", bits="bits", fused="fused xy", new="new total")
        print(f"{'size':>14} {'world':9} " + " ".join(f"{names.get(c, c):>15}" for c in cols)
              + f" {'old GB/s':>8} {'bits GB/s':>9} {'fusedGB/s':>9} {'new GB/s':>8} {'speedup':>7}")
        for (nx, ny, nz), name, t in table:
            n = nx * ny * nz
            f = lambda k: f"{t[k][0]:.4f} ({t[k][1]:.3f})" if k in t else "-"  # noqa: E731
            gbs = lambda b, k: b * n / (t[k][0] * 1e-3) / 1e9  # noqa: E731
            print(f"{f'{nx}x{ny}x{nz}':>14} {name:9} " + " ".join(f"{f(c):>15}" for c in cols)
                  + f" {gbs(4, 'old'):8.0f} {gbs(1.125, 'bits'):9.0f} {gbs(1.125, 'fused'):9.0f} "
                  f"{gbs(2.25, 'new'):8.0f} {t['old'][0] / t['new'][0]:7.2f}")
    print("ALL CORRECT" if all_ok else "SOME CHECKS FAILED")
    return 0 if all_ok else 1


if __name__ == "__main__":
    sys.exit(main())
