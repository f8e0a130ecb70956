"""Import and export of whole worlds: sdfserver snapshots, ``.npy`` arrays, MagicaVoxel ``.vox``.

- ``GET /v1/worlds/{id}/export?format=snapshot|npy|vox`` -> the world's voxels as a file
  (``X-Sdf-Version`` says which version). A snapshot also carries the configuration, so it
  uploads back as the same world.
- ``POST /v1/worlds/import`` with the file as the raw body (any content type) -> 201 and a new
  world holding those voxels. The format is told by the file's first bytes
  (storage/uploads.py); ``format=snapshot|npy|vox``, if given, must agree. For ``npy`` and
  ``vox`` the size is the array's (``.vox``: y-up, see storage/voxfile.py), grown with air
  to whole chunks; ``chunk_size``, ``max_distance``, ``algorithm``, ``storage`` and (``vox``)
  ``model`` are query parameters. A ``.vox`` world keeps the file's colours: its palette is the
  file's and each voxel's value its colour index. A snapshot brings its own configuration
  (palette and storage included).

A dense world is made holding the voxels at version 1. A sparse one (``storage=sparse``) is made
empty and its solid voxels written as edit batches, each within what a client may post, so that
the world is logged, replayed and checked as edited worlds are; its version is then the number of
batches, and the answer waits (up to ``max_wait_ms``) for its field. A sparse world that holds
more device memory than the dense world of its size would says so in the answer's ``warnings``.

The body is spooled to a temporary file as it arrives (``spool.py``), at most
``max_import_bytes``; files are parsed and encoded off the event loop, and decoded sizes are
bounded by ``max_world_voxels`` before anything is allocated.
"""

from __future__ import annotations

import asyncio
import contextlib
from dataclasses import replace
from typing import Any, Iterator

import numpy as np
from fastapi import APIRouter, Query, Request
from fastapi.responses import Response

from sdfserver.api.auth import access_of
from sdfserver.api.bodies import OCTET, respond
from sdfserver.api.routes import batch_record
from sdfserver.api.spool import Spooled, spool_directory, spool_upload
from sdfserver.engine.core import world_config_dict
from sdfserver.engine.rebuild import config_from_dict
from sdfserver.errors import InvalidInput, SdfServerError, VersionNotReached
from sdfserver.geometry import Box
from sdfserver.storage import decode_upload, dump_npy, dump_vox, encode_snapshot, load_npy, load_vox, pad_to_chunks
from sdfserver.storage.snapshot import snapshot_version_of, upload_config
from sdfserver.world import World, WorldConfig

router = APIRouter(prefix="/v1")
FORMATS = "^(snapshot|npy|vox)$"
EXTENSIONS = {"snapshot": "sdfsnap", "npy": "npy", "vox": "vox"}
CONFIG_KEYS = ("size", "chunk_size", "max_distance", "algorithm", "lod_algorithm", "focus", "borders",
               "metric", "signed", "voxel_size", "origin", "palette")  # palette only where the world has one
VOXEL_ROW_BYTES = 8  # an explicit voxel in an edit batch: x, y, z, colour as uint16
SOLID_SCAN_VOXELS = 1 << 22  # voxels scanned for solids at a time, bounding the coordinates held


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
        return Response(body, media_type=OCTET,
                        headers={"X-Sdf-Version": str(snapshot_version_of(body)), **disposition})
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
                       storage: str | None = Query(None, pattern="^(dense|sparse)$", description=(
                           "npy/vox: dense (the default) or sparse, only the bricks near surfaces on the device "
                           "(its solid voxels written as edit batches; its version is their number)")),
                       model: int | None = Query(None, ge=0, description=(
                           "vox: one model of the file alone; left out, the file's whole scene (its "
                           "scene graph placing every model; model 0 of a file without one)"))) -> Response:
    settings = request.app.state.settings
    upload = await spool_upload(request, settings.max_import_bytes, format, spool_directory(settings))
    try:
        config, voxels, snapshot = await asyncio.to_thread(
            parse_upload, upload, settings.max_world_voxels, chunk_size, max_distance, algorithm, storage, model)
    finally:
        upload.close()
    if config.storage == "sparse" and voxels is not None:
        described = await import_sparse(request, config, voxels)
    else:
        described = await request.app.state.engine.create_world(
            world_config_dict(config), access_of(request), voxels=voxels, max_owned=settings.max_worlds_per_key,
            sparse_snapshot=snapshot)
    warning = memory_warning(config, described)
    response = respond(request, {**described, "warnings": [warning]} if warning else described, status_code=201)
    response.headers["Location"] = f"/v1/worlds/{described['id']}"
    return response


def parse_upload(upload: Spooled, limit: int, chunk_size: int, max_distance: int, algorithm: str,
                 storage: str | None, model: int | None) -> tuple[WorldConfig, np.ndarray | None, bytes | None]:
    """(the world's configuration, its voxels (a dense world's grown to whole chunks), a sparse
    world's snapshot file), read off the event loop."""
    format, data = upload.format, upload.view()  # noqa: A001
    if format == "snapshot" and storage is not None:
        raise InvalidInput("storage is for npy and vox imports; a snapshot brings its own configuration")
    sparse, header_config = upload_config(data) if format == "snapshot" else (False, {})
    if sparse:  # a sparse world: its engine checks the bricks
        try:
            config = config_from_dict(header_config)
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInput(f"uploaded snapshot: bad configuration: {exc!r}") from None
        if config.storage != "sparse":  # else no bricks would be read and the world made empty
            raise InvalidInput("uploaded snapshot: format 2 (a sparse world's bricks) with a configuration "
                               f"of storage {config.storage!r}")
        return config.validated(), None, bytes(data)
    if format == "snapshot":
        snap = decode_upload(data, max_voxels=limit)
        try:
            return config_from_dict(snap.config).validated(), snap.voxels, None
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInput(f"uploaded snapshot: bad configuration: {exc!r}") from None
    palette = None
    if format == "npy":
        voxels = load_npy(upload.stream(), max_voxels=limit)
    else:
        voxels, palette = load_vox(data, model=model, max_voxels=limit)
    if chunk_size not in (8, 16, 32, 64, 128):
        raise InvalidInput(f"chunk_size must be one of 8, 16, 32, 64, 128, got {chunk_size}")
    size = tuple(-(-n // chunk_size) * chunk_size for n in voxels.shape[::-1])  # x, y, z in whole chunks
    config = WorldConfig(size=size, chunk_size=chunk_size, max_distance=max_distance, algorithm=algorithm,
                         palette=palette, storage=storage or "dense").validated()
    # a sparse world's voxels become edit batches: no grown copy of them
    return config, voxels if config.storage == "sparse" else pad_to_chunks(voxels, chunk_size), None


async def import_sparse(request: Request, config: WorldConfig, voxels: np.ndarray) -> dict[str, Any]:
    """A sparse world holding ``voxels``: made empty, then its solid voxels written as edit batches
    of at most ``max_voxels_per_batch`` voxels within ``max_request_bytes``, as a client may post
    them; deleted again if a batch is refused (507: its bricks do not fit). Described once its
    field reflects the last batch, or after ``max_wait_ms`` as it is then."""
    settings, engine, access = request.app.state.settings, request.app.state.engine, access_of(request)
    described = await engine.create_world(world_config_dict(config), access, max_owned=settings.max_worlds_per_key)
    world_id, version = described["id"], 0
    per_batch = max(1, min(settings.max_voxels_per_batch, settings.max_request_bytes // VOXEL_ROW_BYTES))
    batches = solid_voxel_batches(voxels, per_batch)
    try:
        while (rows := await asyncio.to_thread(next, batches, None)) is not None:
            version = await engine.apply_edits(world_id, batch_record([{"op": "voxels", "voxels": rows}]), access)
        if version:
            with contextlib.suppress(VersionNotReached):  # a large world: described as it is now
                await engine.read(world_id, "distance", Box((0, 0, 0), (1, 1, 1)), version, access)
    except BaseException:
        with contextlib.suppress(SdfServerError):
            await engine.delete_world(world_id, access)
        raise
    return await engine.describe(world_id, access)


def solid_voxel_batches(voxels: np.ndarray, per_batch: int) -> Iterator[np.ndarray]:
    """The solid voxels of a (z, y, x) array as (N, 4) uint16 rows x, y, z, value, at most
    ``per_batch`` a batch, in the array's order. One loop over stretches of the array, so that
    only one stretch's coordinates are held at a time."""
    flat = voxels.reshape(-1)
    pending: list[np.ndarray] = []
    held = 0
    for start in range(0, flat.size, SOLID_SCAN_VOXELS):
        part = flat[start:start + SOLID_SCAN_VOXELS]
        at = np.flatnonzero(part)
        z, y, x = np.unravel_index(at + start, voxels.shape)
        rows = np.stack([x, y, z, part[at]], axis=1).astype(np.uint16)
        while len(rows):
            take = rows[:per_batch - held]
            pending.append(take)
            held += len(take)
            rows = rows[len(take):]
            if held == per_batch:
                yield np.concatenate(pending)
                pending, held = [], 0
    if held:
        yield np.concatenate(pending)


def memory_warning(config: WorldConfig, described: dict[str, Any]) -> str | None:
    """What to say when a sparse world holds more device memory than the dense world of its size
    would: a stored brick costs more than its voxels would densely (its field beside them, its
    pool's free slots), and at a high cap most bricks lie within the cap of a surface."""
    if described.get("storage") != "sparse":
        return None
    try:
        dense = sum(World.buffer_bytes(replace(config, storage="dense", generate=None).validated()))
    except InvalidInput:  # too large for a dense world: nothing to compare with
        return None
    held = int(described.get("device_bytes") or 0)
    if held <= dense:
        return None
    return (f"this sparse world holds {held / 2**20:.1f} MiB of device memory, more than the {dense / 2**20:.1f} MiB "
            f"a dense world of its size would (its stored bricks, each with its field, and its pools' free slots); "
            f"import it with storage=dense, or with a max_distance below {config.max_distance}, which stores fewer "
            f"bricks")


__all__ = ["router"]
