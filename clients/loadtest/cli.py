"""The command line: create (or open) the world, drive the clients, report."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from loadtest.config import LoadConfig
from loadtest.drive import drive
from loadtest.game import event_loop_kind
from loadtest.report import format_report, report
from sdfclient import Client, SdfClientError

MAX_DURATION_S = 3600.0


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="loadtest", description="N simulated game clients painting random brushes into one world.",
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--url", default="http://127.0.0.1:8000", help="the server's base URL")
    ap.add_argument("--api-key", default=None,
                    help="the server's API key, sent as a bearer token (default: $SDFSERVER_API_KEY; the "
                         "variable keeps it out of the process list)")
    ap.add_argument("--world", default="", help="use this world id instead of creating one")
    ap.add_argument("--size", type=int, nargs=3, default=(64, 64, 64), metavar=("SX", "SY", "SZ"),
                    help="size of the world created for the run")
    ap.add_argument("--chunk-size", type=int, default=16)
    ap.add_argument("--max-distance", type=int, default=255)
    ap.add_argument("--algorithm", default="exact")
    ap.add_argument("--keep-world", action="store_true", help="do not delete the world created for the run")
    ap.add_argument("--clients", type=int, default=4, help="simulated game clients")
    ap.add_argument("--processes", type=int, default=1, help="spread the clients over this many processes")
    ap.add_argument("--duration", type=float, default=10.0, help=f"seconds, at most {MAX_DURATION_S:g}")
    ap.add_argument("--requests", type=int, default=0, help="stop after this many requests (0: duration only)")
    ap.add_argument("--rate", type=float, default=0.0, help="total requests/s (0: as fast as possible)")
    ap.add_argument("--read-every", type=int, default=1, help="read the field after every k-th edit (0: never)")
    ap.add_argument("--read-size", type=int, default=16, help="side of the box read (0: the whole world)")
    ap.add_argument("--read-format", choices=("distance", "packed"), default="distance")
    ap.add_argument("--edits-over", choices=("http", "ws"), default="http",
                    help="post edits over HTTP or send them over each client's WebSocket stream")
    ap.add_argument("--http", choices=("aiohttp", "httptools", "httpx"), default="httptools",
                    help="each client's HTTP connection: loadtest.connection.Connection (aiohttp, little "
                         "client CPU), loadtest.parsed.ParsedConnection (httptools' parser on an asyncio "
                         "protocol, less) or sdfclient.AsyncClient (httpx)")
    ap.add_argument("--loop", choices=("uvloop", "asyncio"), default="uvloop",
                    help="the load generator's event loop (uvloop falls back to asyncio when not installed)")
    ap.add_argument("--ops-per-batch", type=int, default=1, help="brushes per edit batch")
    ap.add_argument("--brush-min", type=float, default=1.0, help="smallest brush radius / half-side, voxels")
    ap.add_argument("--brush-max", type=float, default=8.0, help="largest brush radius / half-side, voxels")
    ap.add_argument("--delete-fraction", type=float, default=0.25, help="share of brushes that erase")
    ap.add_argument("--sphere-fraction", type=float, default=0.5, help="share of brushes that are spheres")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=30.0, help="per-request timeout, seconds")
    ap.add_argument("--json", type=Path, help="write the full results here")
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    args = ap.parse_args(argv)
    if not 0 < args.duration <= MAX_DURATION_S:
        ap.error(f"--duration must be in (0, {MAX_DURATION_S:g}]")
    for name in ("clients", "processes", "ops_per_batch"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be at least 1")
    for name in ("requests", "rate", "read_every", "read_size"):
        if getattr(args, name) < 0:
            ap.error(f"--{name.replace('_', '-')} must not be negative")
    if not 0 <= args.brush_min <= args.brush_max:
        ap.error("need 0 <= --brush-min <= --brush-max")
    if args.api_key is None:
        args.api_key = os.environ.get("SDFSERVER_API_KEY") or None
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    created = not args.world
    try:
        with Client(args.url, api_key=args.api_key, timeout=args.timeout) as client:
            info = (client.create_world(args.size, chunk_size=args.chunk_size, max_distance=args.max_distance,
                                        algorithm=args.algorithm)
                    if created else client.get_world(args.world))
    except SdfClientError as exc:
        print(f"loadtest: cannot {'create' if created else 'open'} the world at {args.url}: {exc}",
              file=sys.stderr)
        return 2
    cfg = LoadConfig(
        url=args.url, world_id=info.id, world_size=info.size, clients=args.clients,
        duration_s=args.duration, requests=args.requests, rate=args.rate, read_every=args.read_every,
        read_size=args.read_size, read_format=args.read_format, ops_per_batch=args.ops_per_batch,
        brush_min=args.brush_min, brush_max=args.brush_max, delete_fraction=args.delete_fraction,
        sphere_fraction=args.sphere_fraction, seed=args.seed, timeout_s=args.timeout,
        edits_over=args.edits_over, http=args.http, loop=event_loop_kind(args.loop), api_key=args.api_key,
    )
    try:
        tally, elapsed = drive(cfg, args.processes, show_progress=not args.quiet)
    finally:
        if created and not args.keep_world:
            with Client(args.url, api_key=args.api_key, timeout=args.timeout) as client:
                try:
                    client.delete_world(info.id)
                except SdfClientError as exc:
                    print(f"loadtest: could not delete world {info.id}: {exc}", file=sys.stderr)
    world = {"id": info.id, "size": list(info.size), "chunk_size": info.chunk_size,
             "max_distance": info.max_distance, "algorithm": info.algorithm, "created": created}
    result = report(cfg, tally, elapsed, world)
    print(format_report(result))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 1 if result["errors"]["count"] else 0
