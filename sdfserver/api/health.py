"""Liveness, readiness and Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, PlainTextResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from sdfserver.api.errors import error_response
from sdfserver.errors import NotReady

router = APIRouter()


@router.get("/livez", summary="The process is up")
async def livez() -> JSONResponse:
    return JSONResponse({"status": "ok"})


@router.get("/readyz", summary="The engine runs and the device works (503 otherwise)")
async def readyz(request: Request) -> JSONResponse:
    engine = request.app.state.engine
    if engine is None or not engine.ready:
        reason = engine.not_ready_reason() if engine is not None else "the engine is not started"
        return error_response(NotReady(reason))
    fronts = request.app.state.fronts
    if fronts is not None and fronts.listening < fronts.wanted:
        return error_response(NotReady(f"{fronts.listening} of {fronts.wanted} front processes listen"))
    journal = request.app.state.journal
    if journal is not None and journal.storage.committer.failure is not None:
        return error_response(journal.storage.committer.failure)  # writes are disabled
    return JSONResponse({"status": "ready", "device": engine.gpu.device_name})


@router.get("/metrics", summary="Prometheus metrics", response_class=PlainTextResponse)
async def metrics(request: Request) -> Response:
    return Response(generate_latest(request.app.state.metrics.registry), media_type=CONTENT_TYPE_LATEST)
