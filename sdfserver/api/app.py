"""The FastAPI application: ``create_app(settings, engine=None)``.

The app holds one Engine in ``app.state.engine``. Given none, it builds one
from the settings when it starts (GpuContext on ``settings.device`` with
``settings.memory_budget_bytes``) and stops it when it shuts down; an engine
passed in is started if it is not running yet and stopped at shutdown too.

The hot request paths (edits, field reads, point queries) go through the fast lane
(``fastlane.py``) in front of FastAPI's routing; ``fast_lane=False`` turns it off.
"""

from __future__ import annotations

import contextlib
import logging
from typing import AsyncIterator

from fastapi import Depends, FastAPI
from fastapi.openapi.utils import get_openapi
from prometheus_client import CollectorRegistry, Counter, Gauge
from starlette.types import Receive, Scope, Send

from sdfserver import __version__
from sdfserver.api import auth, errors, health, models, render_routes, routes, stream, transfer
from sdfserver.api.fastlane import FastLane
from sdfserver.api.gcpauses import GcPauses, freeze_startup_objects
from sdfserver.engine import Engine, EngineLimits, EngineMetrics, Journal
from sdfserver.gpu import GpuContext
from sdfserver.settings import Settings

log = logging.getLogger("sdfserver")


class ApiMetrics:
    """What only the API sees, on the engine's registry (so /metrics shows both)."""

    def __init__(self, registry: CollectorRegistry):
        self.registry = registry
        self.bytes_out = Counter("sdfserver_bytes_out", "Response and stream bytes sent (bodies and frames).",
                                 registry=self.registry)
        self.ws_clients = Gauge("sdfserver_websocket_clients", "Open WebSocket streams.", registry=self.registry)


class App(FastAPI):
    """FastAPI with the fast lane in front: its requests never reach FastAPI's stack."""

    def __init__(self, *args, fast_lane: bool = True, **kwargs):
        super().__init__(*args, **kwargs)
        self.lane = FastLane(super().__call__, self) if fast_lane else None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if self.lane is not None:
            await self.lane(scope, receive, send)
        else:
            await super().__call__(scope, receive, send)


def engine_limits(settings: Settings) -> EngineLimits:
    return EngineLimits(edits=settings.edit_limits(), max_world_voxels=settings.max_world_voxels,
                        max_worlds=settings.max_worlds, max_read_voxels=settings.max_read_voxels,
                        max_subscription_voxels=settings.max_subscription_voxels,
                        max_wait_s=settings.max_wait_ms / 1e3)


def build_engine(settings: Settings, journal: Journal | None = None,
                 metrics: EngineMetrics | None = None) -> Engine:
    """An engine on the device the settings name (not started)."""
    gpu = GpuContext.create(settings.device or None, settings.memory_budget_bytes)
    return Engine(gpu, engine_limits(settings), journal=journal, metrics=metrics)


def create_app(settings: Settings, engine: Engine | None = None, *, fast_lane: bool = True,
               freeze_gc: bool = False) -> FastAPI:
    """``freeze_gc``: at start-up, exempt every object alive from garbage collection and count
    collections on /metrics (``gcpauses.py``); for a server process, not a test's."""
    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if app.state.engine is None:
            app.state.engine = build_engine(settings, metrics=EngineMetrics(registry))
        if not app.state.engine.started:
            app.state.engine.start(warm_up=settings.warm_up)
        if freeze_gc:  # here, once uvicorn has imported all it serves with
            log.info("%d start-up objects exempted from garbage collection", freeze_startup_objects())
            GcPauses(registry)
        try:
            yield
        finally:
            app.state.engine.stop()

    app = App(title="sdfserver", version=__version__, lifespan=lifespan, fast_lane=fast_lane,
              description="Chunked voxel worlds on an OpenCL device with exact Manhattan distance fields. "
                          "See docs/api.md.")
    app.state.settings = settings
    app.state.engine = engine
    app.state.gatekeeper = auth.Gatekeeper(auth.parse_keys(settings.api_keys, settings.api_key_file),
                                           settings.rate_limit_per_s, settings.rate_limit_burst)
    app.state.journal = None  # set by `sdfserver serve` when worlds persist (see durability.py)
    app.state.fronts = None  # the FrontPool under `sdfserver serve --fronts N` (fronts.py)
    registry = engine.metrics.registry if engine is not None else CollectorRegistry()
    app.state.metrics = ApiMetrics(registry)
    errors.install(app)
    app.include_router(health.router)
    app.include_router(transfer.router, dependencies=[Depends(auth.guard)])  # before /worlds/{id}
    app.include_router(routes.router, dependencies=[Depends(auth.guard)])
    app.include_router(stream.router)  # authenticates in the handler (WebSocket close codes)
    # render/pick routes and the web demo at / (issue 4)
    render_routes.install(app, dependencies=[Depends(auth.guard)])

    def openapi() -> dict:
        if app.openapi_schema is None:
            schema = get_openapi(title=app.title, version=app.version, description=app.description,
                                 routes=app.routes)
            schema.setdefault("components", {}).setdefault("schemas", {}).update(models.SCHEMAS)
            app.openapi_schema = errors.document(schema)
        return app.openapi_schema

    app.openapi = openapi
    return app
