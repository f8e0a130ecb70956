"""How long this machine takes to wake a sleeping thread or process, and whether the CPUs' idle
states are what makes it slow.

    python tools/wake_probe.py [--rounds 2000] [--gap-us 300] [--hold-latency-us N]

Prints the guest's idle driver and states, then the p50/p90 of a one-way wake, measured as half a
ping-pong: between two threads of one process (``threading.Event``, a futex), and between two
processes over a socket pair (what the service's hops are made of). Each ping waits ``--gap-us``
first so the other side has gone to sleep, as a lone client's hops do. ``--hold-latency-us N``
holds ``/dev/cpu_dma_latency`` at N µs while measuring (the kernel's PM QoS request, what
``tuned``'s latency profiles do; root only): with 0, idle CPUs poll instead of halting.
"""

from __future__ import annotations

import argparse
import glob
import os
import socket
import struct
import threading
import time
from contextlib import contextmanager
from pathlib import Path


def idle_states() -> str:
    driver = Path("/sys/devices/system/cpu/cpuidle/current_driver")
    lines = [f"idle driver: {driver.read_text().strip() if driver.exists() else 'none'}"]
    for state in sorted(glob.glob("/sys/devices/system/cpu/cpu0/cpuidle/state*")):
        name, latency = (Path(state, f).read_text().strip() for f in ("name", "latency"))
        lines.append(f"  {Path(state).name}: {name}, exit latency {latency} µs")
    for parameter in sorted(glob.glob("/sys/module/haltpoll/parameters/*")):
        lines.append(f"  haltpoll {Path(parameter).name} = {Path(parameter).read_text().strip()}")
    return "\n".join(lines)


@contextmanager
def held_latency(microseconds: int | None):
    if microseconds is None:
        yield
        return
    fd = os.open("/dev/cpu_dma_latency", os.O_WRONLY)
    try:
        os.write(fd, struct.pack("i", microseconds))
        yield
    finally:
        os.close(fd)  # closing the file drops the request


def percentiles(seconds: list[float]) -> str:
    ordered = sorted(seconds)
    pick = lambda q: ordered[min(len(ordered) - 1, int(q * len(ordered)))] * 1e6 / 2  # noqa: E731
    return f"one-way p50 {pick(0.5):6.1f} µs, p90 {pick(0.9):6.1f} µs"


def threads(rounds: int, gap_s: float) -> list[float]:
    ping, pong = threading.Event(), threading.Event()

    def answer() -> None:
        for _ in range(rounds):
            ping.wait()
            ping.clear()
            pong.set()

    other = threading.Thread(target=answer)
    other.start()
    seconds = []
    for _ in range(rounds):
        time.sleep(gap_s)
        start = time.perf_counter()
        ping.set()
        pong.wait()
        seconds.append(time.perf_counter() - start)
        pong.clear()
    other.join()
    return seconds


def processes(rounds: int, gap_s: float) -> list[float]:
    mine, theirs = socket.socketpair()
    child = os.fork()
    if child == 0:
        mine.close()
        for _ in range(rounds):
            theirs.sendall(theirs.recv(1))
        os._exit(0)
    theirs.close()
    seconds = []
    for _ in range(rounds):
        time.sleep(gap_s)
        start = time.perf_counter()
        mine.sendall(b"x")
        mine.recv(1)
        seconds.append(time.perf_counter() - start)
    os.waitpid(child, 0)
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2000)
    parser.add_argument("--gap-us", type=float, default=300.0)
    parser.add_argument("--hold-latency-us", type=int, default=None)
    args = parser.parse_args()
    print(idle_states())
    with held_latency(args.hold_latency_us):
        held = "held at %s µs" % args.hold_latency_us if args.hold_latency_us is not None else "not held"
        print(f"cpu_dma_latency {held}, gap {args.gap_us:g} µs, {args.rounds} rounds")
        print(f"  threads (Event):      {percentiles(threads(args.rounds, args.gap_us / 1e6))}")
        print(f"  processes (socket):   {percentiles(processes(args.rounds, args.gap_us / 1e6))}")


if __name__ == "__main__":
    main()
