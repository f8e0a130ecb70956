"""The server's host overhead per edit batch, next to the device time it bought.

Runs a command (a load test) against a running ``sdfserver serve`` and reads, before and after,
the CPU time (``/proc/<pid>/stat``, all threads) of the launcher and of its child processes (the
engine and API processes), and the server's ``/metrics``:

    python tools/service_overhead.py --pid $SERVER_PID --url http://127.0.0.1:8765 -- \\
        python clients/loadtest --url http://127.0.0.1:8765 --clients 64 --processes 8 \\
        --duration 15 --size 256 256 256 --read-every 0

prints batches, engine steps (batches merged per step), and per batch: server CPU, recompute
wall time and recompute device time. Server CPU minus device time is what the host adds.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import urllib.request

COUNTERS = ("sdfserver_edit_batches_total", "sdfserver_engine_steps_total", "sdfserver_recompute_seconds_sum",
            "sdfserver_recompute_device_seconds_total")


def cpu_seconds(pid: int, tid: int | None = None) -> float:
    """utime + stime of process ``pid`` (all its threads), or of its thread ``tid`` alone."""
    path = f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat"
    fields = open(path).read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def children(pid: int) -> list[int]:
    """The launcher's child processes: its engine and API processes."""
    try:
        return [int(c) for c in open(f"/proc/{pid}/task/{pid}/children").read().split()]
    except OSError:
        return []


def children_cpu_seconds(pids: list[int]) -> float:
    total = 0.0
    for pid in pids:
        try:
            total += cpu_seconds(pid)
        except OSError:  # a process that exited (and was started again) drops out
            pass
    return total


def metrics(url: str) -> dict[str, float]:
    out = dict.fromkeys(COUNTERS, 0.0)
    for line in urllib.request.urlopen(url + "/metrics", timeout=10).read().decode().splitlines():
        name = re.sub(r"\{.*\}", "", line.split(" ", 1)[0])
        if name in out:
            out[name] += float(line.rsplit(" ", 1)[1])  # summed over algorithms
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pid", type=int, required=True, help="the sdfserver serve process")
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- then the load-test command")
    args = ap.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        ap.error("give the load-test command after --")
    processes = children(args.pid)
    m0, c0, f0 = metrics(args.url), cpu_seconds(args.pid), children_cpu_seconds(processes)
    code = subprocess.run(command).returncode
    m1, c1, f1 = metrics(args.url), cpu_seconds(args.pid), children_cpu_seconds(processes)
    d = {k: m1[k] - m0[k] for k in COUNTERS}
    batches, steps = d["sdfserver_edit_batches_total"], d["sdfserver_engine_steps_total"]
    if batches <= 0:
        print("no edit batches were applied", file=sys.stderr)
        return 1
    per = lambda seconds: seconds / batches * 1e6  # noqa: E731
    print(f"{batches:.0f} batches in {steps:.0f} engine steps ({batches / max(steps, 1):.1f} per step); per batch: "
          f"server CPU {per(c1 - c0):.0f} us, recompute wall {per(d['sdfserver_recompute_seconds_sum']):.0f} us, "
          f"recompute device {per(d['sdfserver_recompute_device_seconds_total']):.0f} us"
          + (f"; {len(processes)} child processes (engine, API): {per(f1 - f0):.0f} us CPU per batch between them"
             if processes else ""))
    return code


if __name__ == "__main__":
    raise SystemExit(main())
