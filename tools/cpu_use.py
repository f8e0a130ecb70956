"""Where a load's CPU went: the host's busy share and the server's processes' CPU seconds.

    python tools/cpu_use.py snap SERVER_PID > before.json
    ... the load ...
    python tools/cpu_use.py snap SERVER_PID > after.json
    python tools/cpu_use.py diff before.json after.json [--requests N]

``snap`` records /proc/stat's totals and the CPU seconds of the server (the launcher), its
engine processes (the children with a thread named ``engine``), its other children (the API
processes) and the engine processes' CPU seconds by thread name, summed over the engines (the
server names its threads: ``sdfserver/threadnames.py``; threads of the OpenCL driver keep the
process's name).
``diff`` prints the host's busy share over the interval, each part's cores, and with
``--requests`` each part's CPU per request and the engine processes' threads' CPU per request.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from service_overhead import children, cpu_seconds, children_cpu_seconds

TICK = os.sysconf("SC_CLK_TCK")


def snap(pid: int) -> dict:
    cpu = open("/proc/stat").readline().split()[1:]
    values = [int(v) for v in cpu]
    idle = values[3] + values[4]  # idle + iowait
    kids = children(pid)
    by_kid = {kid: thread_seconds(kid) for kid in kids}
    engines = [kid for kid, split in by_kid.items() if "engine" in split]
    threads: dict[str, float] = {}
    for engine in engines:
        for name, seconds in by_kid[engine].items():
            threads[name] = threads.get(name, 0.0) + seconds
    return {"at": time.monotonic(), "host_busy_s": (sum(values[:8]) - idle) / TICK,
            "host_total_s": sum(values[:8]) / TICK, "cpus": os.cpu_count(), "launcher_s": cpu_seconds(pid),
            "engine_s": children_cpu_seconds(engines), "engines": len(engines),
            "api_s": children_cpu_seconds([kid for kid in kids if kid not in engines]), "engine_threads_s": threads}


def thread_seconds(pid: int) -> dict[str, float]:
    """CPU seconds of each of ``pid``'s threads, summed by thread name (a pool's threads, numbered,
    under one name)."""
    out: dict[str, float] = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            name = open(f"/proc/{pid}/task/{tid}/comm").read().strip().rstrip("0123456789").rstrip("_")
            out[name] = out.get(name, 0.0) + cpu_seconds(pid, int(tid))
        except OSError:  # the thread ended meanwhile
            continue
    return out


def thread_split(before: dict, after: dict, requests: int) -> dict[str, float]:
    """The engine process's threads' CPU per request (µs), by name, busiest first."""
    old, new = before.get("engine_threads_s", {}), after.get("engine_threads_s", {})
    used = {name: (new[name] - old.get(name, 0.0)) / requests * 1e6 for name in new}
    return dict(sorted(((n, u) for n, u in used.items() if u >= 0.5), key=lambda item: -item[1]))


def diff(before: dict, after: dict, requests: int) -> None:
    wall = after["at"] - before["at"]
    busy = after["host_busy_s"] - before["host_busy_s"]
    total = after["host_total_s"] - before["host_total_s"]
    print(f"host: {busy / total:.0%} busy of {after['cpus']} CPUs over {wall:.1f} s ({busy / wall:.1f} CPUs)")
    for part in ("engine", "api", "launcher"):
        used = after[f"{part}_s"] - before[f"{part}_s"]
        per = f", {used / requests * 1e6:.0f} µs a request" if requests else ""
        print(f"{part}: {used / wall:.2f} CPUs{per}")
    if requests:
        print(f"host, all processes: {busy / requests * 1e6:.0f} µs a request")
        split = thread_split(before, after, requests)
        threads = ", ".join(f"{n} {u:.0f} µs" for n, u in split.items())
        print(f"engine processes ({after.get('engines', 1)}) by thread: {threads}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("snap").add_argument("pid", type=int)
    d = sub.add_parser("diff")
    d.add_argument("before")
    d.add_argument("after")
    d.add_argument("--requests", type=int, default=0)
    args = parser.parse_args()
    if args.command == "snap":
        json.dump(snap(args.pid), sys.stdout)
    else:
        diff(json.load(open(args.before)), json.load(open(args.after)), args.requests)


if __name__ == "__main__":
    main()
