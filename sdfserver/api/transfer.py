"""Import and export of whole worlds: sdfserver snapshots, ``.npy`` arrays, MagicaVoxel ``.vox``.

- ``GET /v1/worlds/{id}/export?format=snapshot|npy|vox`` -> the world's voxels as a file
  (``X-Sdf-Version`` says which version). A snapshot also carries the configuration, so it
  uploads back as the same world.
- ``POST /v1/worlds/import?format=snapshot|npy|vox`` with the file as the raw body (any
  content type) -> 201 and a new world holding those voxels at version 1. For ``npy`` and
  ``vox`` the size is the array's (``.vox``: y-up, see storage/voxfile.py), grown with air
  to whole chunks; ``chunk_size``, ``max_distance``, ``algorithm`` and (``vox``) ``model`` are
  query parameters. A snapshot brings its own configuration.

Files are parsed and encoded off the event loop; bodies are bounded by ``max_request_bytes``
and decoded sizes by ``max_world_voxels`` before anything is allocated.
"""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import Response

from sdfserver.api.auth import check_world_quota
from sdfserver.api.bodies import OCTET, read_body, respond
from sdfserver.engine.restore import config_from_dict
from sdfserver.errors import InvalidInput
from sdfserver.storage import (
    decode_upload, dump_npy, dump_vox, encode_snapshot, load_npy, load_vox, pad_to_chunks,
)
from sdfserver.world import WorldConfig

router = APIRouter(prefix="/v1")
FORMATS = "^(snapshot|npy|vox)$"
EXTENSIONS = {"snapshot": "sdfsnap", "npy": "npy", "vox": "vox"}
CONFIG_KEYS = ("size", "chunk_size", "max_distance", "algorithm", "lod_algorithm", "focus")


@router.get("/worlds/{world_id}/export", summary="Download the world's voxels as a snapshot, .npy or .vox",
            response_class=Response, responses={200: {"content": {OCTET: {}}}})
async def export_world(request: Request, world_id: str,
                       format: str = Query("snapshot", pattern=FORMATS, description="snapshot, npy or vox")
                       ) -> Response:
    engine = request.app.state.engine
    described = await engine.describe(world_id)
    read = await engine.read(world_id, "voxels")
    config = {k: described[k] for k in CONFIG_KEYS}
    encode = {"snapshot": lambda: encode_snapshot(read.version, config, read.array),
              "npy": lambda: dump_npy(read.array), "vox": lambda: dump_vox(read.array)}[format]
    body = await asyncio.to_thread(encode)
    request.app.state.metrics.bytes_out.inc(len(body))
    return Response(body, media_type=OCTET, headers={
        "X-Sdf-Version": str(read.version),
        "Content-Disposition": f'attachment; filename="{world_id}.{EXTENSIONS[format]}"'})


@router.post("/worlds/import", status_code=201, summary="Create a world from a snapshot, .npy or .vox file",
             openapi_extra={"requestBody": {"required": True, "content": {OCTET: {"schema": {
                 "type": "string", "format": "binary"}}}}})
async def import_world(request: Request,
                       format: str = Query(..., pattern=FORMATS, description="snapshot, npy or vox"),
                       chunk_size: int = Query(16, description="npy/vox: chunk side, 8..128"),
                       max_distance: int = Query(255, description="npy/vox: distance cap, 1..255"),
                       algorithm: str = Query("exact", description="npy/vox: the field's algorithm"),
                       model: int = Query(0, ge=0, description="vox: which model of the file")) -> Response:
    settings = request.app.state.settings
    principal = check_world_quota(request)
    data = await read_body(request, settings.max_request_bytes)
    limit = settings.max_world_voxels

    def parse() -> tuple[WorldConfig, Any]:
        if format == "snapshot":
            snap = decode_upload(data, max_voxels=limit)
            try:
                return config_from_dict(snap.config), snap.voxels
            except (KeyError, TypeError, ValueError) as exc:
                raise InvalidInput(f"uploaded snapshot: bad configuration: {exc!r}") from None
        voxels = load_npy(data, max_voxels=limit) if format == "npy" else load_vox(data, model=model,
                                                                                  max_voxels=limit)
        if chunk_size not in (8, 16, 32, 64, 128):
            raise InvalidInput(f"chunk_size must be one of 8, 16, 32, 64, 128, got {chunk_size}")
        voxels = pad_to_chunks(voxels, chunk_size)
        return WorldConfig(size=voxels.shape[::-1], chunk_size=chunk_size, max_distance=max_distance,
                           algorithm=algorithm), voxels

    config, voxels = await asyncio.to_thread(parse)
    described = await request.app.state.engine.create_world(config.validated(), owner=principal.name,
                                                            voxels=voxels)
    response = respond(request, described, status_code=201)
    response.headers["Location"] = f"/v1/worlds/{described['id']}"
    return response


__all__ = ["router"]
