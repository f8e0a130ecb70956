"""py-spy's raw stacks (``py-spy record --threads -f raw``) thread by thread: each thread's share
of the samples and the stacks (innermost frames) it spent them in; with ``--cpu`` an
``engine_drive.py`` JSON, each thread's CPU per batch beside its name.

    python tools/profile_threads.py profile-idle-64.txt profile-gil-64.txt --cpu clients-64.json
"""

from __future__ import annotations

import argparse
import collections
import json
import re

from profile_summary import read_stacks


def summarize(path: str, depth: int, top: int, cpu: dict[int, float]) -> None:
    stacks: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    total = 0
    for frames, count in read_stacks(path):
        inner = " <- ".join(f.split(" (")[0] for f in frames[-depth:][::-1])
        stacks[frames[0]][inner] += count
        total += count
    print(f"== {path}: {total} samples")
    for thread, counter in sorted(stacks.items(), key=lambda t: -sum(t[1].values())):
        tid = re.search(r"\((\d+)\)", thread)
        spent = f", {cpu[int(tid[1])]:.1f} µs CPU a batch" if tid and int(tid[1]) in cpu else ""
        print(f"-- {thread}: {sum(counter.values())} samples{spent}")
        for inner, n in counter.most_common(top):
            print(f"  {n:6d} {100 * n / total:5.1f}%  {inner[:150]}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="+")
    parser.add_argument("--cpu", help="an engine_drive.py JSON of the same engine")
    parser.add_argument("--depth", type=int, default=3)
    parser.add_argument("--top", type=int, default=12)
    args = parser.parse_args()
    cpu = {}
    if args.cpu:
        for key, us in json.load(open(args.cpu)).get("thread_cpu_us_per_batch", {}).items():
            cpu[int(key.split()[0])] = us
    for path in args.paths:
        try:
            summarize(path, args.depth, args.top, cpu)
        except OSError as exc:
            print(f"no samples in {path}: {exc}")


if __name__ == "__main__":
    main()
