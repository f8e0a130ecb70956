"""Where an engine process's GIL goes under load: py-spy (``pip install py-spy``) samples
``tools/engine_drive.py``'s engine process with ``--gil`` (only the thread holding the GIL is
sampled, so the samples add up to the time the process's Python work is serialized), and this
prints each function's share of the engine process's samples, inclusive and as the innermost
Python frame (C code a function calls counts as its own time).

    PYTHONPATH=$PWD:$PWD/clients/python python3 tools/gil_profile.py --out gil.txt -- \\
        --size 128 --worlds 1 --clients 64 --duration 8 -- --device nvidia

Everything after the first ``--`` goes to engine_drive.py. ``--summarize FILE`` prints the table of
an earlier recording (py-spy's raw format) without running anything.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import shutil
import subprocess
import sys

LINE = re.compile(r":\d+\)$")


def summarize(path: str, top: int) -> None:
    """The engine process: the one whose stacks run engine_main."""
    per_process: dict[str, list[tuple[list[str], int]]] = collections.defaultdict(list)
    for line in open(path, errors="replace"):
        stack, _, count = line.rstrip("\n").rpartition(" ")
        if not count.isdigit():
            continue
        frames = stack.split(";")
        process = next((f.split(":")[0] for f in reversed(frames) if f.startswith("process ")), "?")
        per_process[process].append(([LINE.sub(")", f) for f in frames if not f.startswith(("process ", "thread "))],
                                     int(count)))
    engine = [p for p, stacks in per_process.items() if any("serve_engine" in f for s, _ in stacks for f in s)]
    if not engine:
        sys.exit(f"{path}: no process ran serve_engine")
    stacks = [(s, n) for s, n in per_process[engine[0]] if any("Thread._bootstrap" in f for f in s)]  # its threads
    total = sum(n for _, n in stacks)
    inclusive, own = collections.Counter(), collections.Counter()
    for frames, n in stacks:
        for f in set(frames):
            inclusive[f] += n
        own[frames[-1]] += n
    print(f"{engine[0]}: {total} samples holding the GIL on its threads")
    for title, counter in (("inclusive", inclusive), ("own (innermost Python frame)", own)):
        print(f"\n{title}:")
        for f, n in counter.most_common(top):
            print(f"  {n / total:6.1%}  {f}")


def main() -> None:
    argv = sys.argv[1:]
    drive = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="gil.txt", help="py-spy's raw recording")
    parser.add_argument("--rate", type=int, default=1000, help="samples a second")
    parser.add_argument("--top", type=int, default=40)
    parser.add_argument("--summarize", help="an earlier recording to print, running nothing")
    args = parser.parse_args(argv)
    if args.summarize:
        summarize(args.summarize, args.top)
        return
    spy = shutil.which("py-spy")
    if spy is None:
        sys.exit("py-spy is not installed: pip install py-spy")
    drive_py = os.path.join(os.path.dirname(os.path.abspath(__file__)), "engine_drive.py")
    subprocess.run([spy, "record", "--gil", "--subprocesses", "--rate", str(args.rate), "--format", "raw",
                    "--output", args.out, "--", sys.executable, drive_py, *drive], check=True)
    summarize(args.out, args.top)


if __name__ == "__main__":
    main()
