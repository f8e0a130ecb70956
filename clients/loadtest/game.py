"""One game client (edit, then read its field with ``min_version``), and a worker's clients on one
event loop."""

from __future__ import annotations

import array
import asyncio
import contextlib
import functools
import math
import time
from dataclasses import dataclass, field
from typing import Any, Coroutine, TypeVar

import httpx

from loadtest.collector import FullCollections
from loadtest.config import Brushes, LoadConfig
from loadtest.connection import Connection
from loadtest.parsed import ParsedConnection
from loadtest.schedule import schedule_for
from sdfclient import AsyncClient, RateLimited, SdfClientError, ServerError
from sdfclient.stream import Stream

T = TypeVar("T")
LEAN_CLIENTS = {"aiohttp": Connection, "httptools": ParsedConnection}  # each bounds a whole exchange


@dataclass
class Tally:
    """A worker's measurements. Latencies count from when each request was due (loadtest.schedule:
    at a set rate, its slot; without one, when it left); service times from when it actually left."""

    edit_ms: array.array = field(default_factory=lambda: array.array("d"))
    edit_service_ms: array.array = field(default_factory=lambda: array.array("d"))
    edit_at_s: array.array = field(default_factory=lambda: array.array("d"))  # when each edit was due
    read_ms: array.array = field(default_factory=lambda: array.array("d"))
    read_service_ms: array.array = field(default_factory=lambda: array.array("d"))
    round_trip_ms: array.array = field(default_factory=lambda: array.array("d"))  # edit + its read
    round_trip_service_ms: array.array = field(default_factory=lambda: array.array("d"))
    send_lag_ms: array.array = field(default_factory=lambda: array.array("d"))  # at a set rate: left - due
    missed: int = 0  # at a set rate: requests already due while their client still waited
    unsent: int = 0  # at a set rate: requests due before the end that never left
    errors: dict[str, int] = field(default_factory=dict)
    error_messages: dict[str, str] = field(default_factory=dict)  # the first of each code
    cpu_s: float = 0.0  # the load generator's own CPU time (time.process_time) over the run
    frozen_objects: int = 0  # exempted from its garbage collector before the run (collector.settle)
    full_collections: int = 0  # its full collections during the run, and the longest
    longest_collection_s: float = 0.0

    @property
    def count(self) -> int:
        return self.answered + sum(self.errors.values())

    @property
    def answered(self) -> int:
        """Requests that succeeded."""
        return len(self.edit_ms) + len(self.read_ms)

    def error(self, exc: Exception) -> None:
        key = exc.code if isinstance(exc, ServerError) else type(exc).__name__
        self.errors[key] = self.errors.get(key, 0) + 1
        self.error_messages.setdefault(key, str(exc)[:300])

    def merge(self, other: "Tally") -> None:
        """Add a worker's tally to this one."""
        for name in ("edit_ms", "edit_service_ms", "edit_at_s", "read_ms", "read_service_ms", "round_trip_ms",
                     "round_trip_service_ms", "send_lag_ms"):
            getattr(self, name).extend(getattr(other, name))
        self.missed += other.missed
        self.unsent += other.unsent
        for key, n in other.errors.items():
            self.errors[key] = self.errors.get(key, 0) + n
        for key, message in other.error_messages.items():
            self.error_messages.setdefault(key, message)
        self.cpu_s += other.cpu_s
        self.frozen_objects += other.frozen_objects
        self.full_collections += other.full_collections
        self.longest_collection_s = max(self.longest_collection_s, other.longest_collection_s)


class Budget:
    """Request tickets shared by the clients of one worker, and the deadline."""

    def __init__(self, requests: int, deadline: float):
        self.left = requests if requests > 0 else None
        self.deadline = deadline

    def take(self) -> bool:
        if time.perf_counter() >= self.deadline:
            return False
        if self.left is None:
            return True
        if self.left <= 0:
            return False
        self.left -= 1
        return True

    @property
    def out_of_tickets(self) -> bool:
        return self.left is not None and self.left <= 0


async def game_client(index: int, cfg: LoadConfig, tally: Tally, budget: Budget, start: float) -> None:
    brushes = Brushes(cfg.seed * 1_000_003 + index, cfg)
    schedule = schedule_for(index, cfg.clients, cfg.rate, start)
    edits_sent = 0
    async with contextlib.AsyncExitStack() as stack:
        if cfg.http in LEAN_CLIENTS:
            client = LEAN_CLIENTS[cfg.http](cfg.url, api_key=cfg.api_key, timeout=cfg.timeout_s)
        else:
            # retries=0: a refusal is counted as the server gave it, not waited out inside the client
            client = AsyncClient(cfg.url, api_key=cfg.api_key, timeout=cfg.timeout_s, retries=0,
                                 limits=httpx.Limits(max_connections=1))
        await stack.enter_async_context(client)
        if cfg.edits_over == "ws":  # what AsyncClient.stream opens, whichever HTTP client reads
            stream = await stack.enter_async_context(Stream.connect(cfg.url, cfg.world_id, api_key=cfg.api_key))
            edit = stream.edit
        else:
            edit = functools.partial(client.edit, cfg.world_id)
        # Connection's timeout bounds the whole exchange; httpx's are per phase, the stream has none.
        if cfg.http in LEAN_CLIENTS and cfg.edits_over == "http":
            send_edit = edit
        else:
            def send_edit(batch: list[dict]):
                return asyncio.wait_for(edit(batch), cfg.timeout_s)
        pending_read = None
        answered_at = -math.inf  # the client's last answer (or error): a slot due before it was missed
        while True:
            due = await schedule.turn()
            if not budget.take():
                if not budget.out_of_tickets:  # the deadline ended the run
                    tally.unsent += schedule.unsent_before(budget.deadline)
                return
            sent = time.perf_counter()
            if not schedule.closed:
                tally.send_lag_ms.append((sent - due) * 1e3)
                if due < answered_at:
                    tally.missed += 1
            due = min(due, sent)  # from here on: when the latency counts from
            try:
                if pending_read is not None:
                    box, version, edit_ms, edit_service_ms = pending_read
                    pending_read = None
                    block = await client.read_field(cfg.world_id, box, format=cfg.read_format,
                                                    min_version=version)
                    if block.version < version:
                        tally.errors["stale_read"] = tally.errors.get("stale_read", 0) + 1
                        continue
                    answered = time.perf_counter()
                    read_ms, read_service_ms = (answered - due) * 1e3, (answered - sent) * 1e3
                    tally.read_ms.append(read_ms)
                    tally.read_service_ms.append(read_service_ms)
                    tally.round_trip_ms.append(edit_ms + read_ms)
                    tally.round_trip_service_ms.append(edit_service_ms + read_service_ms)
                    continue
                batch, center = brushes.batch()
                version = await send_edit(batch)
                answered = time.perf_counter()
                edit_ms, edit_service_ms = (answered - due) * 1e3, (answered - sent) * 1e3
                tally.edit_ms.append(edit_ms)
                tally.edit_service_ms.append(edit_service_ms)
                tally.edit_at_s.append(due - start)
                edits_sent += 1
                if cfg.read_every and edits_sent % cfg.read_every == 0:
                    pending_read = (brushes.read_box(center), version, edit_ms, edit_service_ms)
            except (SdfClientError, TimeoutError) as exc:
                tally.error(exc)
                if isinstance(exc, RateLimited):  # a well-behaved game client waits as told
                    pause = exc.retry_after_s if exc.retry_after_s is not None else 1.0
                    await asyncio.sleep(max(0.0, min(pause, budget.deadline - time.perf_counter())))
            finally:
                answered_at = time.perf_counter()


async def run_clients(cfg: LoadConfig, indices: list[int], requests: int, tally: Tally,
                      progress=None) -> float:
    cpu_start = time.process_time()
    start = time.perf_counter()
    budget = Budget(requests, start + cfg.duration_s)
    tasks = [asyncio.create_task(game_client(i, cfg, tally, budget, start)) for i in indices]
    with FullCollections() as full:
        while not all(t.done() for t in tasks):
            await asyncio.wait(tasks, timeout=0.25)
            if progress is not None:
                progress(tally)
    tally.full_collections += full.count
    tally.longest_collection_s = max(tally.longest_collection_s, full.longest_s)
    for t in tasks:
        t.result()  # a bug in the load test itself surfaces here
    tally.cpu_s += time.process_time() - cpu_start
    return time.perf_counter() - start


def event_loop_kind(wanted: str) -> str:
    """uvloop when asked for and installed (``uvicorn[standard]`` brings it), else asyncio."""
    if wanted == "uvloop":
        try:
            import uvloop  # noqa: F401
        except ImportError:
            return "asyncio"
    return wanted


def run_loop(cfg: LoadConfig, coroutine: Coroutine[Any, Any, T]) -> T:
    """Run ``coroutine`` on the configured loop: the generator's own CPU per request is part of
    every latency it measures, and uvloop spends less of it."""
    if event_loop_kind(cfg.loop) == "asyncio":
        return asyncio.run(coroutine)
    import uvloop
    with asyncio.Runner(loop_factory=uvloop.new_event_loop) as runner:
        return runner.run(coroutine)
