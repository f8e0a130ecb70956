"""Import and export of whole worlds: sdfserver snapshots, ``.npy`` arrays, MagicaVoxel ``.vox``.

- ``GET /v1/worlds/{id}/export?format=snapshot|npy|vox`` -> the world's voxels as a file
  (``X-Sdf-Version`` says which version). A snapshot also carries the configuration, so it
  uploads back as the same world.
- ``POST /v1/worlds/import`` with the file as the raw body (any content type) -> 201 and a new
  world holding those voxels at version 1. The format is told by the file's first bytes
  (storage/uploads.py); ``format=snapshot|npy|vox``, if given, must agree. For ``npy`` and
  ``vox`` the size is the array's (``.vox``: y-up, see storage/voxfile.py), grown with air
  to whole chunks; ``chunk_size``, ``max_distance``, ``algorithm`` and (``vox``) ``model`` are
  query parameters. A ``.vox`` world keeps the file's colours: its palette is the file's and each
  voxel's value its colour index. A snapshot brings its own configuration (palette included).

Files are parsed and encoded off the event loop. An upload may carry ``max_request_bytes``
voxels in its format's encoding plus that format's framing, so every export of a world within
the limit imports back; decoded sizes are bounded by ``max_world_voxels`` before anything is
allocated.
"""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import Response
from starlette.requests import ClientDisconnect

from sdfserver.api.auth import access_of
from sdfserver.api.bodies import OCTET, header, respond
from sdfserver.engine.core import world_config_dict
from sdfserver.engine.rebuild import config_from_dict
from sdfserver.errors import BodyTooLarge, InvalidInput
from sdfserver.storage import (
    decode_upload, dump_npy, dump_vox, encode_snapshot, load_npy, load_vox, pad_to_chunks,
)
from sdfserver.storage.snapshot import upload_config
from sdfserver.storage.uploads import SNIFF_BYTES, upload_format, upload_limit_bytes
from sdfserver.world import WorldConfig

router = APIRouter(prefix="/v1")
FORMATS = "^(snapshot|npy|vox)$"
EXTENSIONS = {"snapshot": "sdfsnap", "npy": "npy", "vox": "vox"}
CONFIG_KEYS = ("size", "chunk_size", "max_distance", "algorithm", "lod_algorithm", "focus", "borders",
               "metric", "signed", "voxel_size", "origin", "palette")  # palette only where the world has one


@router.get("/worlds/{world_id}/export", summary="Download the world's voxels as a snapshot, .npy or .vox",
            response_class=Response, responses={200: {"content": {OCTET: {}}}})
async def export_world(request: Request, world_id: str,
                       format: str = Query("snapshot", pattern=FORMATS, description="snapshot, npy or vox")
                       ) -> Response:
    engine = request.app.state.engine
    described = await engine.describe(world_id, access_of(request))  # admitted once, here
    disposition = {"Content-Disposition": f'attachment; filename="{world_id}.{EXTENSIONS[format]}"'}
    if format == "snapshot" and described.get("storage") == "sparse":  # its bricks, not every voxel
        body = await engine.export_bricks(world_id, access_of(request))
        request.app.state.metrics.bytes_out.inc(len(body))
        return Response(body, media_type=OCTET, headers=disposition)
    read = await engine.read(world_id, "voxels")
    config = {k: described[k] for k in CONFIG_KEYS if k in described}
    encode = {"snapshot": lambda: encode_snapshot(read.version, config, read.array),
              "npy": lambda: dump_npy(read.array),
              "vox": lambda: dump_vox(read.array, described.get("palette"))}[format]
    body = await asyncio.to_thread(encode)
    request.app.state.metrics.bytes_out.inc(len(body))
    return Response(body, media_type=OCTET, headers={"X-Sdf-Version": str(read.version), **disposition})


@router.post("/worlds/import", status_code=201, summary="Create a world from a snapshot, .npy or .vox file",
             openapi_extra={"requestBody": {"required": True, "content": {OCTET: {"schema": {
                 "type": "string", "format": "binary"}}}}})
async def import_world(request: Request,
                       format: str | None = Query(None, pattern=FORMATS, description=(
                           "snapshot, npy or vox: told by the file's first bytes; if given, must agree")),
                       chunk_size: int = Query(16, description="npy/vox: chunk side, 8..128"),
                       max_distance: int = Query(255, description="npy/vox: distance cap, 1..255"),
                       algorithm: str = Query("exact", description="npy/vox: the field's algorithm"),
                       model: int | None = Query(None, ge=0, description=(
                           "vox: one model of the file alone; left out, the file's whole scene (its "
                           "scene graph placing every model; model 0 of a file without one)"))) -> Response:
    settings = request.app.state.settings
    format, data = await read_upload(request, settings.max_request_bytes, format)  # noqa: A001
    limit = settings.max_world_voxels

    def parse() -> tuple[WorldConfig, Any]:
        sparse, header_config = upload_config(data) if format == "snapshot" else (False, {})
        if sparse:  # a sparse world: its engine checks the bricks
            try:
                config = config_from_dict(header_config)
            except (KeyError, TypeError, ValueError) as exc:
                raise InvalidInput(f"uploaded snapshot: bad configuration: {exc!r}") from None
            if config.storage != "sparse":  # else no bricks would be read and the world made empty
                raise InvalidInput("uploaded snapshot: format 2 (a sparse world's bricks) with a configuration "
                                   f"of storage {config.storage!r}")
            return config, None
        if format == "snapshot":
            snap = decode_upload(data, max_voxels=limit)
            try:
                return config_from_dict(snap.config), snap.voxels
            except (KeyError, TypeError, ValueError) as exc:
                raise InvalidInput(f"uploaded snapshot: bad configuration: {exc!r}") from None
        palette = None
        if format == "npy":
            voxels = load_npy(data, max_voxels=limit)
        else:
            voxels, palette = load_vox(data, model=model, max_voxels=limit)
        if chunk_size not in (8, 16, 32, 64, 128):
            raise InvalidInput(f"chunk_size must be one of 8, 16, 32, 64, 128, got {chunk_size}")
        voxels = pad_to_chunks(voxels, chunk_size)
        return WorldConfig(size=voxels.shape[::-1], chunk_size=chunk_size, max_distance=max_distance,
                           algorithm=algorithm, palette=palette), voxels

    config, voxels = await asyncio.to_thread(parse)
    described = await request.app.state.engine.create_world(
        world_config_dict(config.validated()), access_of(request), voxels=voxels,
        max_owned=request.app.state.settings.max_worlds_per_key,
        sparse_snapshot=data if config.storage == "sparse" else None)
    response = respond(request, described, status_code=201)
    response.headers["Location"] = f"/v1/worlds/{described['id']}"
    return response


async def read_upload(request: Request, max_voxels: int, given: str | None) -> tuple[str, bytes]:
    """The upload's format and bytes. The format, read from the first bytes, sets the body's
    limit (storage/uploads.py); a body over it is refused before it is read in full."""
    length = header(request, b"content-length")
    declared = int(length) if length is not None and length.isdigit() else 0
    chunks: list[bytes] = []
    size, fmt, limit, more = 0, None, 0, True
    while more:
        message = await request.receive()
        if message["type"] == "http.disconnect":
            raise ClientDisconnect()
        chunks.append(message.get("body", b""))
        size += len(chunks[-1])
        more = message.get("more_body", False)
        if fmt is None and (size >= SNIFF_BYTES or not more):
            fmt = upload_format(b"".join(chunks)[:SNIFF_BYTES], given)
            limit = upload_limit_bytes(fmt, max_voxels)
        if fmt is not None and max(size, declared) > limit:
            raise BodyTooLarge(f"a {fmt} upload of {max(size, declared)} bytes exceeds the limit of {limit} bytes "
                           f"({max_voxels} voxels, max_request_bytes, in the {fmt} format)")
    return fmt, b"".join(chunks)


__all__ = ["router"]
