"""Liveness, readiness and Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, PlainTextResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from sdfserver.api.engines import not_ready
from sdfserver.api.errors import error_response
from sdfserver.errors import NotReady, WritesDisabled

router = APIRouter()


@router.get("/livez", summary="The process is up")
async def livez() -> JSONResponse:
    return JSONResponse({"status": "ok"})


@router.get("/readyz", summary="Every engine runs and its device works (503 otherwise)")
async def readyz(request: Request) -> JSONResponse:
    engines = request.app.state.engine
    if engines is None:
        return error_response(NotReady("the engine is not started"))
    statuses = await engines.status()
    failure = not_ready(statuses)
    if failure is not None:
        return error_response(failure)
    for status in statuses:
        if status.writes_disabled is not None:
            return error_response(WritesDisabled(status.writes_disabled))
    devices = [s.device for s in statuses]
    # an engine held by one step past busy_step_ms still serves (200), but says what holds it
    busy = [{"engine": i, "device": s.device, **s.busy} for i, s in enumerate(statuses) if s.busy]
    return JSONResponse({"status": "ready", "device": devices[0], "devices": devices, "busy": busy})


@router.get("/metrics", summary="Prometheus metrics", response_class=PlainTextResponse)
async def metrics(request: Request) -> Response:
    """The engines' registries (fetched from each), then what the API processes share: the counts
    below the app (counts.py), every API process's process_* and their GC pauses, and the build
    (process_metrics.py). Whichever API process answers, the text is the same but for what
    changed between two scrapes."""
    api = request.app.state.metrics
    api.report()  # this process's counts, before the engine's text is taken
    engines = await request.app.state.engine.metrics_text()
    return Response(engines + generate_latest(api.registry).decode(), media_type=CONTENT_TYPE_LATEST)
