"""The load test (``python clients/loadtest``):  N simulated game clients painting random brushes into one world.

Each game client loops: post one edit batch of random brushes (spheres and
boxes, placing and deleting, random positions and brush sizes from a seed —
the dissertation's benchmark mode, §3.5), and after every ``--read-every``-th
edit read the field around it with ``min_version`` set to the version the edit
returned (read-your-writes). Requests go out as fast as possible or at a set
total ``--rate``; the run stops at ``--duration`` seconds or after
``--requests`` requests, whichever comes first (both are bounded).

    python clients/loadtest --url http://127.0.0.1:8000 --clients 64 --duration 30 --json out.json

Against a server with API keys, set ``SDFSERVER_API_KEY`` (or ``--api-key``); a
``429`` counts as a ``rate_limited`` error and the client waits its Retry-After.

Reports throughput, p50/p95/p99 latency and errors per request kind, and for
``--read-every`` runs the round trip (an edit's latency plus its read's: brush
edit to field ready, read-your-writes); prints a
progress line once a second (to stderr); ``--json`` writes everything. Exits 1
when any request failed. Without ``--rate`` the load is a closed loop: each client
sends when its last answer comes, and latency runs from the send to the answer.
With ``--rate`` it is an open loop (``loadtest.schedule``): each request has a slot
fixed at the start, latency runs from that slot (a client still waiting for an
answer sends its overdue requests as soon as it can, and a server's stall shows in
every request due during it), the service time from the actual send is reported
beside it, and so are how many requests left late and by how much.
With ``--processes P`` the clients are spread over P processes (one Python
process tops out at a few thousand requests per second).

Each game client holds one connection. With ``--http httptools`` (the default) it is a
``loadtest.parsed.ParsedConnection`` (an asyncio protocol read by httptools' parser, the one
uvicorn serves with), so that the generator costs little next to the server it measures;
``--http aiohttp`` uses ``loadtest.connection.Connection`` (aiohttp's client, about twice the
generator CPU a request), ``--http httpx`` ``sdfclient.AsyncClient``. The report
says what the load generator itself cost: its processes' CPU time per request
(``client_cpu_us_per_request``).

Modules: ``config`` (the run's settings, the brushes), ``schedule`` (when each request is due),
``game`` (one game client, a worker's clients on one event loop), ``drive`` (spreading them over
processes), ``report`` (percentiles, the progress line, the result document), ``parsed`` (the
httptools connection), ``connection`` (the aiohttp one), ``cli``.
"""

from __future__ import annotations

from loadtest.cli import MAX_DURATION_S, main, parse_args
from loadtest.config import Brushes, LoadConfig
from loadtest.drive import drive
from loadtest.game import Budget, Tally, event_loop_kind, game_client, run_clients, run_loop
from loadtest.report import ProgressLine, format_report, latency_summary, report

__all__ = [
    "MAX_DURATION_S", "Brushes", "Budget", "LoadConfig", "ProgressLine", "Tally", "drive", "event_loop_kind",
    "format_report", "game_client", "latency_summary", "main", "parse_args", "report", "run_clients", "run_loop",
]
