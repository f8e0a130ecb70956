"""How long an fdatasync of a small log record takes on this disk, back to back and after idling.

    python tools/fsync_probe.py /path/on/the/disk [--records 400] [--gaps-ms 0,1,2.5]

For each gap between syncs (default 0, 1 and 2.5 ms) and each way of writing the record — appending
(the file grows), overwriting pre-zeroed blocks, overwriting fallocated blocks — writes
150-byte records, each followed by ``fdatasync``, and prints p50/p90/p99 of write + sync.
"""

from __future__ import annotations

import argparse
import os
import time

RECORD = b"x" * 150
GAPS_MS = "0,1,2.5"
MODES = ("append", "zeroed", "fallocate")


def probe(directory: str, mode: str, gap_s: float, records: int) -> list[float]:
    path = os.path.join(directory, "fsync-probe.bin")
    if mode == "append":
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND, 0o644)
    else:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)
        size = records * len(RECORD) + 8192
        if mode == "zeroed":
            os.write(fd, bytes(size))
        else:
            os.posix_fallocate(fd, 0, size)
    os.fsync(fd)
    seconds = []
    try:
        for i in range(records):
            if gap_s:
                time.sleep(gap_s)
            start = time.perf_counter()
            if mode == "append":
                os.write(fd, RECORD)
            else:
                os.pwrite(fd, RECORD, i * len(RECORD))
            os.fdatasync(fd)
            seconds.append(time.perf_counter() - start)
    finally:
        os.close(fd)
        os.unlink(path)
    return sorted(seconds)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("directory", help="a directory on the disk to measure (the data directory's disk)")
    ap.add_argument("--records", type=int, default=400)
    ap.add_argument("--gaps-ms", default=GAPS_MS, help="idle time before each write, comma-separated")
    args = ap.parse_args()
    for gap_s in [float(g) / 1e3 for g in args.gaps_ms.split(",")]:
        for mode in MODES:
            s = probe(args.directory, mode, gap_s, args.records)
            pick = lambda q: s[min(len(s) - 1, int(len(s) * q))] * 1e6  # noqa: E731
            print(f"{mode:9s} gap {gap_s * 1e3:3.1f} ms   p50 {pick(0.5):8.1f} us  p90 {pick(0.9):8.1f}  "
                  f"p99 {pick(0.99):8.1f}", flush=True)


if __name__ == "__main__":
    main()
