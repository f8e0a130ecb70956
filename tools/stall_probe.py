"""Is this host's CPU steady? A probe to run beside the server (Linux only).

It does fixed units of arithmetic (about 0.2 ms each, then sleeps as long) and prints every unit
that took over ``--threshold-ms`` of wall time, with how much of that the guest kernel counted as
the probe running (``/proc/thread-self/schedstat``) and as waiting on a run queue. A unit the
kernel says ran for 4 ms that does 0.2 ms of work on a quiet host ran slower below the guest
(another tenant, the hypervisor): every process on the machine, the server's engine thread
included, slows down with it. Steal, IRQ and softirq ticks (``/proc/stat``) are printed each
second they change. See docs/benchmarks.md, "How we measure".

    python3 tools/stall_probe.py --seconds 13

With ``--per-cpu`` it runs one such probe pinned to each CPU at once (nothing else needs to run)
and prints, per CPU, how many units were slow, and for each slow unit how many other CPUs had a
slow unit overlapping it: stalls that hit every CPU together come from below the guest, and a
host that has them with no server running will have them under the server too.

    python3 tools/stall_probe.py --per-cpu --seconds 8 --threshold-ms 1
"""

from __future__ import annotations

import argparse
import collections
import multiprocessing
import os
import time


def schedstat_ns() -> tuple[int, int]:
    """(time run on a CPU, time waited on a run queue) of this thread, in nanoseconds."""
    run, wait, _ = open("/proc/thread-self/schedstat").read().split()
    return int(run), int(wait)


def cpu_ticks() -> dict[str, int]:
    fields = open("/proc/stat").readline().split()[1:]
    names = ("user", "nice", "system", "idle", "iowait", "irq", "softirq", "steal")
    return dict(zip(names, map(int, fields)))


def work(n: int) -> int:
    total = 0
    for i in range(n):
        total += i * i
    return total


def calibrate(unit_s: float = 2e-4) -> int:
    """The loop count of one unit of about ``unit_s`` on this CPU now."""
    n = 1000
    while True:
        started = time.perf_counter()
        work(n)
        if time.perf_counter() - started > unit_s:
            return n
        n *= 2


def stamp() -> str:
    now = time.time()
    return f"{time.strftime('%H:%M:%S', time.localtime(now))},{int(now % 1 * 1000):03d}"


def pinned_probe(cpu: int, seconds: float, threshold_ms: float, results: multiprocessing.Queue) -> None:
    """One CPU's probe for --per-cpu: its unit count and its slow units' (start, end) times."""
    os.sched_setaffinity(0, {cpu})
    n = calibrate()
    slow, units, end = [], 0, time.monotonic() + seconds
    while time.monotonic() < end:
        started = time.monotonic()
        work(n)
        finished = time.monotonic()
        units += 1
        if (finished - started) * 1e3 > threshold_ms:
            slow.append((started, finished))
        time.sleep(2e-4)
    results.put((cpu, units, slow))


def per_cpu(seconds: float, threshold_ms: float) -> None:
    cpus = sorted(os.sched_getaffinity(0))
    results: multiprocessing.Queue = multiprocessing.Queue()
    probes = [multiprocessing.Process(target=pinned_probe, args=(c, seconds, threshold_ms, results)) for c in cpus]
    for p in probes:
        p.start()
    found = sorted(results.get() for _ in probes)
    for p in probes:
        p.join()
    slow = [(start, end, cpu) for cpu, _, units in found for start, end in units]
    print(f"per-CPU probe, {seconds:g} s, units of ~0.2 ms, slow = over {threshold_ms:g} ms")
    print("slow units per CPU:", ", ".join(f"{cpu}: {len(units)}" for cpu, _, units in found),
          f"(of about {found[0][1]} each)")
    print("worst units, ms:", [round((e - s) * 1e3, 1) for s, e, _ in sorted(slow, key=lambda u: u[0] - u[1])[:8]])
    together = collections.Counter(
        len({c2 for s2, e2, c2 in slow if c2 != cpu and s2 < end and e2 > start}) for start, end, cpu in slow)
    print("slow units by how many other CPUs were slow at the same time:",
          ", ".join(f"{k}: {v}" for k, v in sorted(together.items())))
    everywhere = sum(v for k, v in together.items() if k >= len(cpus) // 2)
    print(f"with at least half the other CPUs slow too: {everywhere} of {len(slow)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="how long to probe")
    ap.add_argument("--threshold-ms", type=float, default=3.0, help="report units slower than this")
    ap.add_argument("--per-cpu", action="store_true", help="one probe pinned to each CPU, all at once")
    args = ap.parse_args()
    if args.per_cpu:
        per_cpu(args.seconds, args.threshold_ms)
        return
    n = calibrate()
    end = time.time() + args.seconds
    units = stalls = 0
    worst = 0.0
    ticks, ticks_at = cpu_ticks(), time.time()
    while time.time() < end:
        run0, wait0 = schedstat_ns()
        started = time.perf_counter()
        work(n)
        wall_ms = (time.perf_counter() - started) * 1e3
        run1, wait1 = schedstat_ns()
        units += 1
        worst = max(worst, wall_ms)
        if wall_ms > args.threshold_ms:
            stalls += 1
            print(f"{stamp()} unit {wall_ms:.1f} ms: guest says ran {(run1 - run0) / 1e6:.1f} ms, "
                  f"queued {(wait1 - wait0) / 1e6:.1f} ms", flush=True)
        time.sleep(2e-4)
        if time.time() - ticks_at >= 1.0:
            now = cpu_ticks()
            changed = {k: now[k] - ticks[k] for k in ("irq", "softirq", "steal") if now[k] != ticks[k]}
            if changed:
                print(f"{stamp()} /proc/stat ticks: " + ", ".join(f"{k} {v}" for k, v in changed.items()), flush=True)
            ticks, ticks_at = now, time.time()
    print(f"probe: {units} units of ~0.2 ms, {stalls} over {args.threshold_ms:g} ms, worst {worst:.1f} ms")


if __name__ == "__main__":
    main()
