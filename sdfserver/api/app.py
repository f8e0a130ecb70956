"""The FastAPI application of one API process: ``create_app(settings, clients)``.

The app reaches the engines only through ``app.state.engine`` (``engines.Engines``): typed
requests to engine processes (``EngineClient``, as ``sdfserver serve`` starts it) or to an
engine in this process (``create_app(settings, engine=Engine(...))``: tests and tools, through
``LocalEngineClient``, the same messages). It holds no device state.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
from pathlib import Path
from typing import Any, AsyncIterator, Sequence

from fastapi import Depends, FastAPI
from fastapi.openapi.utils import get_openapi
from prometheus_client import CollectorRegistry

from sdfserver import __version__
from sdfserver.api import auth, bodies, errors, health, models, render_routes, routes, stream, transfer
from sdfserver.api.counts import CountsCollector, SharedCounts
from sdfserver.api.engine_client import BaseClient, LocalEngineClient
from sdfserver.api.engines import Engines, LocalPlacement
from sdfserver.api.process_metrics import ApiProcessesCollector
from sdfserver.gcpauses import GcPauses, freeze_startup_objects
from sdfserver.heap import keep_freed_memory
from sdfserver.settings import Settings

log = logging.getLogger("sdfserver")
REPORT_EVERY_S = 0.5  # how often an API process reports the bytes it sent to the engine's metrics


class ApiMetrics:
    """What only an API process sees: counted here, reported to the first engine (so that
    /metrics, from any API process, shows every process's counts); what happens to connections
    below the app, and each API process's pid and GC pauses, are in ``counts``, shared by the API
    processes (``counts.py``), which any of them shows (``process_metrics.py``)."""

    def __init__(self, counts: SharedCounts | None = None) -> None:
        self.registry = CollectorRegistry()  # what the API processes share, shown by whichever answers
        self.counts = counts if counts is not None else SharedCounts()
        self.counts.claim(os.getpid())
        self.registry.register(CountsCollector(self.counts))
        self.registry.register(ApiProcessesCollector(self.counts))
        self.engines: Engines | None = None
        self.bytes_out = _Accumulator()
        self.ws_clients = _WebSocketGauge(self)

    def report(self) -> None:
        sent = self.bytes_out.take()
        if sent and self.engines is not None:
            self.engines.count(bytes_out=sent)

    async def report_forever(self) -> None:
        while True:
            await asyncio.sleep(REPORT_EVERY_S)
            self.report()


class _Accumulator:
    def __init__(self) -> None:
        self.value = 0

    def inc(self, amount: int = 1) -> None:
        self.value += amount

    def take(self) -> int:
        value, self.value = self.value, 0
        return value


class _WebSocketGauge:
    def __init__(self, metrics: ApiMetrics):
        self.metrics = metrics

    def inc(self) -> None:
        if self.metrics.engines is not None:
            self.metrics.engines.count(websocket_clients=1)

    def dec(self) -> None:
        if self.metrics.engines is not None:
            self.metrics.engines.count(websocket_clients=-1)


FOLLOW_EVERY_S = 0.5  # how often an API process looks for a cluster engine's new address


async def follow_addresses(clients: Sequence[Any], path: Path) -> None:
    """Reconnect a client whose engine now listens elsewhere (a cluster's engine actor restarted
    on another node): the cluster process rewrites ``path`` ([{index, input, output}]) then."""
    seen = None
    while True:
        await asyncio.sleep(FOLLOW_EVERY_S)
        try:
            stamp = path.stat().st_mtime_ns
            if stamp == seen:
                continue
            addresses = json.loads(path.read_text())
            seen = stamp
        except (OSError, ValueError):
            continue  # not written yet, or being replaced: next time
        for entry in addresses:
            client = clients[entry["index"]]
            if (client.input_address, client.output_address) != (entry["input"], entry["output"]):
                log.warning("engine %d now listens at %s; reconnecting", entry["index"], entry["input"])
                client.relocate(entry["input"], entry["output"])


class RebalanceLeader:
    """Whether this API process rebalances: the one that holds the data directory's
    ``rebalance.lock`` (another takes it over when that process is gone)."""

    def __init__(self, path: Path):
        self.path = path
        self._held = None

    def __call__(self) -> bool:
        if self._held is None:
            from sdfserver.storage.lock import try_lock

            self._held = try_lock(self.path)
        return self._held is not None


def create_app(settings: Settings, engine: Any = None, *, clients: Sequence[BaseClient] | None = None,
               freeze_gc: bool = False, addresses_file: str | None = None,
               counts: SharedCounts | None = None) -> FastAPI:
    """``clients``: the engine processes' clients (started with the app); ``engine``: an Engine
    in this process instead (started if it is not running, stopped at shutdown). ``counts``:
    the API processes' shared connection counts (this process's own when left out).
    ``freeze_gc``: exempt start-up objects from garbage collection and count collections on
    /metrics (``gcpauses.py``), and keep freed heap memory (``heap.py``), for a server process."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        local = engine
        if clients is None and local is None:
            from sdfserver.engine.proc import engine_limits
            from sdfserver.engine import Engine, EngineMetrics
            from sdfserver.gpu import GpuContext

            local = Engine(GpuContext.create(settings.device or None, settings.memory_budget_bytes),
                           engine_limits(settings), metrics=EngineMetrics())
        if local is not None and not local.started:
            local.start(warm_up=settings.warm_up)
        if app.state.engine is None:
            use(list(clients) if clients is not None else [LocalEngineClient(local, settings)])
        engine_clients = app.state.engine.clients
        for client in engine_clients:
            await client.start()
        reporter = asyncio.create_task(app.state.metrics.report_forever())
        follower = None if addresses_file is None else asyncio.create_task(
            follow_addresses(engine_clients, Path(addresses_file)))
        rebalancer = None
        if settings.rebalance_below > 0 and settings.persist and len(engine_clients) > 1:
            rebalancer = asyncio.create_task(app.state.engine.rebalance_forever(
                settings.rebalance_below, settings.rebalance_every_s, settings.move_release_timeout_s,
                RebalanceLeader(Path(settings.data_dir) / "rebalance.lock")))
        if freeze_gc:  # here, once uvicorn has imported all it serves with
            log.info("%d start-up objects exempted from garbage collection", freeze_startup_objects())
            GcPauses(None, publish=app.state.metrics.counts.set)  # /metrics sums every API process's
            keep_freed_memory()
        try:
            yield
        finally:
            reporter.cancel()
            for task in (rebalancer, follower):
                if task is not None:
                    task.cancel()
            app.state.metrics.report()
            for client in engine_clients:
                await client.stop()
            if local is not None:
                local.stop()

    app = FastAPI(title="sdfserver", version=__version__, lifespan=lifespan,
                  description="Chunked voxel worlds on an OpenCL device with exact Manhattan distance fields. "
                              "See docs/api.md.")
    app.state.settings = settings
    app.state.engine = None  # Engines: the engines' clients, routed by world id
    app.state.metrics = ApiMetrics(counts)

    def use(engine_clients: list[BaseClient]) -> None:
        app.state.engine = Engines(LocalPlacement(engine_clients), settings.max_wait_ms / 1e3)
        app.state.metrics.engines = app.state.engine

    if engine is not None:  # usable without the lifespan too (httpx.ASGITransport runs none)
        use([LocalEngineClient(engine, settings)])
    app.state.gatekeeper = auth.Gatekeeper(auth.parse_keys(settings.api_keys, settings.api_key_file),
                                           settings.rate_limit_per_s)
    errors.install(app)
    # the hot routes first: a request is matched against the routes in order
    app.include_router(routes.router, dependencies=[Depends(auth.guard)])
    app.include_router(health.router)
    app.include_router(transfer.router, dependencies=[Depends(auth.guard)])
    app.include_router(stream.router)  # authenticates in the handler (WebSocket close codes)
    render_routes.install(app, dependencies=[Depends(auth.guard)])

    def openapi() -> dict:
        if app.openapi_schema is None:
            schema = get_openapi(title=app.title, version=app.version, description=app.description,
                                 routes=app.routes)
            schema.setdefault("components", {}).setdefault("schemas", {}).update(models.SCHEMAS)
            app.openapi_schema = errors.document(bodies.document_answers(schema))
        return app.openapi_schema

    app.openapi = openapi
    return app
