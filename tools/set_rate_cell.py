"""One table cell for a load test at a set rate (``clients/loadtest --rate R --json PATH``): the
edits' p99 timed from each request's slot, the same requests' p99 timed from when each left (the
service time), and what keeping the schedule cost (requests that left late, the longest lag).

The benchmark scripts' summaries (``engine_limit.sh``, ``service_ab.sh``) import it, so that
every set-rate figure they print names both methods the same way:

    python3 tools/set_rate_cell.py RESULT.json   # prints the cell
"""

from __future__ import annotations

import json
import sys

HEADER = "p99 from slot / from send (sends late, longest lag)"


def cell(result: dict) -> str:
    edits = result["edits"]
    schedule = result.get("schedule", {})
    if schedule.get("loop") != "open":  # no --rate, or a load test that timed every request from its send
        return f"{edits['latency_ms']['p99']:.1f} ms from send (not an open loop)"
    lag = schedule["send_lag_ms"] or {"max": 0.0}
    return (f"{edits['latency_ms']['p99']:.1f} / {edits['service_time_ms']['p99']:.1f} ms "
            f"({schedule['late']} of {schedule['sent']}, {lag['max']:.1f} ms)")


def cell_from(path: str) -> str:
    """The cell for the result document at ``path``, or why there is none."""
    try:
        with open(path) as f:
            return cell(json.load(f))
    except (OSError, ValueError, KeyError) as exc:
        return f"failed: {exc}"


if __name__ == "__main__":
    print(cell_from(sys.argv[1]))
