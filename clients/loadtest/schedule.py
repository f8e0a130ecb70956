"""When each of one game client's requests is due, and the time its latency counts from.

At a set ``--rate`` the load is an open loop: a client's k-th request is due at
``first_due + k * interval``, fixed when the run starts and never moved. A request that cannot
leave on time (its client is still waiting for the last answer) leaves as soon as it can, and its
latency still counts from when it was due. Timing it from when it actually left, and letting the
schedule slide, would drop exactly the requests a stalled server kept from being sent, so a
200 ms stall would show as one slow request instead of every request due during it — the
coordinated omission that wrk2 and HdrHistogram correct. What it cost to keep the schedule is
reported beside the latencies: how many requests were due while their client still waited
(``missed``), how late each left (the send lag), and how many were due before the end but never
left.

An event loop's timer wakes up to about a millisecond off (uvloop rounds to whole milliseconds,
either way): a client asks to be woken ``TIMER_LEAD_S`` before its slot, so that its own timer's
lateness is seldom counted as the server's, and a request that leaves before its slot is timed from
when it left (a latency is never less than its service time).

Without a rate the load is a closed loop: each client sends its next request when its last is
answered, and latency counts from when each left (there is no schedule to be late for).
"""

from __future__ import annotations

import asyncio
import math
import time

TIMER_LEAD_S = 0.0005  # about half uvloop's timer granularity


class OpenLoop:
    """One client's share of a set rate: ``clients / rate`` seconds apart, from ``first_due``."""

    closed = False

    def __init__(self, interval_s: float, first_due: float):
        self.interval_s = interval_s
        self.first_due = first_due
        self.handed_out = 0

    def next_due(self) -> float:
        return self.first_due + self.handed_out * self.interval_s

    async def turn(self) -> float:
        """Wait for the next slot; when it is due (latency counts from there, or from the send if
        that was earlier)."""
        due = self.next_due()
        self.handed_out += 1
        delay = due - TIMER_LEAD_S - time.perf_counter()
        if delay > 0:
            await asyncio.sleep(delay)
        return due

    def unsent_before(self, deadline: float) -> int:
        """Slots due before ``deadline`` that never left, counting the last one handed out (its
        client reached it only after the deadline)."""
        due = self.next_due() - self.interval_s
        return math.ceil((deadline - due) / self.interval_s) if due < deadline else 0


class ClosedLoop:
    """No schedule: the next request leaves as soon as the last is answered."""

    closed = True

    async def turn(self) -> float:
        return time.perf_counter()

    def unsent_before(self, deadline: float) -> int:
        return 0


def schedule_for(index: int, clients: int, rate: float, start: float) -> OpenLoop | ClosedLoop:
    """Client ``index``'s schedule: the total rate split evenly, the clients' slots interleaved."""
    if rate <= 0:
        return ClosedLoop()
    interval_s = clients / rate
    return OpenLoop(interval_s, start + interval_s * index / clients)
