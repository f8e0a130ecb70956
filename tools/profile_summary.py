"""Summarize py-spy's raw stacks (``py-spy record -f raw``): samples per thread, the functions
that were running (self) and those on the stack (inclusive), most first.

    python tools/profile_summary.py profile-engine-64.txt [--top 25]
"""

from __future__ import annotations

import argparse
import collections
from typing import Iterator


def read_stacks(path: str) -> Iterator[tuple[list[str], int]]:
    """(frames, outermost first, and their sample count) for each line of py-spy's raw output."""
    for line in open(path).read().splitlines():
        stack, _, count = line.rpartition(" ")
        if count.isdigit():
            yield stack.split(";"), int(count)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("path")
    parser.add_argument("--top", type=int, default=25)
    args = parser.parse_args()
    running, on_stack, threads = collections.Counter(), collections.Counter(), collections.Counter()
    total = 0
    try:
        stacks = list(read_stacks(args.path))
    except OSError as exc:
        print(f"no samples: {exc}")
        return
    for frames, samples in stacks:
        total += samples
        threads[frames[0]] += samples
        running[frames[-1]] += samples
        for frame in set(frames):
            on_stack[frame] += samples
    print(f"{total} samples; by thread entry: " + ", ".join(f"{n} {f[:60]}" for f, n in threads.most_common(4)))
    print("running:")
    for frame, n in running.most_common(args.top):
        print(f"  {n:6d} {100 * n / max(total, 1):5.1f}%  {frame[:140]}")
    print("on the stack:")
    for frame, n in on_stack.most_common(args.top * 2):
        print(f"  {n:6d} {100 * n / max(total, 1):5.1f}%  {frame[:140]}")


if __name__ == "__main__":
    main()
