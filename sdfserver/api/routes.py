"""HTTP API v1: worlds, edits, field and voxel reads, point queries.

Handlers translate between requests and engine commands; they reach the engine
only through ``request.app.state.engine`` and never touch the device.
"""

from __future__ import annotations

import base64
import time
from typing import Any

import numpy as np
from fastapi import APIRouter, Query, Request
from fastapi.responses import Response

from sdfserver import wire
from sdfserver.api.auth import access_of, principal_of
from sdfserver.api.bodies import MSGPACK, OCTET, Encoded, decode_body, header, respond, wants_msgpack
from sdfserver.api.engines import Engines
from sdfserver.api.models import CreateWorldBody, EditsBody, MoveWorldBody, PatchWorldBody, QueryBody, request_body
from sdfserver.engine.core import world_config_dict
from sdfserver.errors import Forbidden, InvalidEdit, InvalidInput, TooLarge
from sdfserver.geometry import Box
from sdfserver.incoming import short
from sdfserver.storage.codec import encode_batch
from sdfserver.world import Focus, WorldConfig
from sdfserver.world_config import TerrainSpec

router = APIRouter(prefix="/v1")
LITTLE_ENDIAN = {name: np.dtype(name).newbyteorder("<")  # reads' wire dtypes
                 for name in ("uint8", "uint16", "int16", "float32")}


def engine_of(request: Request) -> Engines:
    return request.app.state.engine


def max_owned(request: Request) -> int:
    return request.app.state.settings.max_worlds_per_key


FIELD_OPTIONS = ("metric", "signed", "voxel_size", "origin", "palette")


def field_options(body: Any) -> dict[str, Any]:
    """The field options a create or PATCH body sets (left out: the world's default or current)."""
    return {k: getattr(body, k) for k in FIELD_OPTIONS if getattr(body, k) is not None}


def _focus(body: Any) -> Focus | None:
    return None if body is None else Focus(tuple(body.center), tuple(body.size))


@router.post("/worlds", status_code=201, openapi_extra=request_body(CreateWorldBody),
             summary="Create a world (version 0, all air)")
async def create_world(request: Request) -> Response:
    body = CreateWorldBody.model_validate(await decode_body(request))
    config = WorldConfig(size=tuple(body.size), chunk_size=body.chunk_size, max_distance=body.max_distance,
                         algorithm=body.algorithm, lod_algorithm=body.lod_algorithm, focus=_focus(body.focus),
                         borders=body.borders, storage=body.storage,
                         generate=None if body.generate is None else TerrainSpec(**body.generate.model_dump()),
                         **field_options(body))
    described = await engine_of(request).create_world(world_config_dict(config), access_of(request),
                                                      max_owned=max_owned(request))
    response = respond(request, described, status_code=201)
    response.headers["Location"] = f"/v1/worlds/{described['id']}"
    return response


@router.get("/worlds", summary="List worlds")
async def list_worlds(request: Request) -> Response:
    principal = principal_of(request)
    worlds = [w for w in await engine_of(request).list_worlds(access_of(request)) if principal.sees(w["owner"])]
    return respond(request, {"worlds": worlds})


@router.get("/engines", summary="The engines: device, process, worlds, free device memory")
async def list_engines(request: Request) -> Response:
    engines = engine_of(request)
    statuses = await engines.status()
    sees_all = principal_of(request).admin  # world ids are other tenants' business
    return respond(request, [{"engine": i, "address": getattr(client, "input_address", "in this process"),
                              "ready": s.ready, "reason": s.reason, "device": s.device, "pid": s.pid,
                              "free_bytes": s.free_bytes, "worlds": len(s.worlds), "epoch": s.epoch,
                              **({"world_ids": sorted(s.worlds)} if sees_all else {})}
                             for i, (client, s) in enumerate(zip(engines.clients, statuses))])


@router.post("/engines/rebalance", summary="Move worlds off engines short of device memory (admin; one pass)")
async def rebalance(request: Request,
                    below: float = Query(0.25, gt=0, lt=1, description="an engine whose free memory is under this "
                                         "fraction of its budget moves its smallest world that fits elsewhere")
                    ) -> Response:
    if not principal_of(request).admin:
        raise Forbidden("rebalancing engines needs an admin key")
    settings = request.app.state.settings
    moves = await engine_of(request).rebalance(below, settings.move_release_timeout_s)
    return respond(request, {"moves": moves})


@router.get("/worlds/{world_id}", summary="Describe a world")
async def describe_world(request: Request, world_id: str) -> Response:
    return respond(request, await engine_of(request).describe(world_id, access_of(request)))


@router.patch("/worlds/{world_id}", openapi_extra=request_body(PatchWorldBody),
              summary="Change algorithm, focus, cap, borders, metric or sign (the field is recomputed), "
                      "voxel size, origin or palette")
async def patch_world(request: Request, world_id: str) -> Response:
    body = PatchWorldBody.model_validate(await decode_body(request))
    changes: dict[str, Any] = {k: getattr(body, k) for k in ("algorithm", "lod_algorithm", "max_distance", "borders")
                               if getattr(body, k) is not None}
    changes.update(field_options(body))
    if "focus" in body.model_fields_set:
        changes["focus"] = None if body.focus is None else {"center": list(body.focus.center),
                                                            "size": list(body.focus.size)}
    engine = engine_of(request)
    if changes:
        await engine.reconfigure(world_id, changes, access_of(request))
        return respond(request, await engine.describe(world_id))
    return respond(request, await engine.describe(world_id, access_of(request)))


@router.post("/worlds/{world_id}/move", openapi_extra=request_body(MoveWorldBody),
             summary="Move a world to another engine (admin): its writes meanwhile wait, none lost or doubled")
async def move_world(request: Request, world_id: str) -> Response:
    body = MoveWorldBody.model_validate(await decode_body(request))
    if not principal_of(request).admin:
        raise Forbidden("moving a world between engines needs an admin key")
    settings = request.app.state.settings
    described = await engine_of(request).move_world(world_id, body.engine, access_of(request),
                                                     release_timeout_s=settings.move_release_timeout_s)
    return respond(request, described)


@router.delete("/worlds/{world_id}", status_code=204, summary="Delete a world")
async def delete_world(request: Request, world_id: str) -> Response:
    await engine_of(request).delete_world(world_id, access_of(request))
    return Response(status_code=204)


def _edits_wire(body: Any, max_ops: int) -> list[dict[str, Any]]:
    if not isinstance(body, dict) or set(body) != {"edits"}:
        raise InvalidEdit("the body must be an object with one field, 'edits'")
    raw = body["edits"]
    if isinstance(raw, list) and len(raw) > max_ops:
        raise TooLarge(f"{len(raw)} operations in one batch; the limit is {max_ops}")
    if isinstance(raw, list):
        for i, op in enumerate(raw):
            if isinstance(op, dict) and wire.is_blob(op.get("voxels")):
                raw[i] = {**op, "voxels": wire.unpack_array(op["voxels"], f"edits[{i}].voxels")}
    return raw


MAX_BATCH_ID_CHARS = 128


def batch_id_of(request: Request) -> str | None:
    """The client's id for this batch (``Idempotency-Key``): a retry with the same id is answered
    with the first attempt's version instead of being applied again."""
    key = header(request, b"idempotency-key")
    if key is None:
        return None
    if not 0 < len(key) <= MAX_BATCH_ID_CHARS or not key.isascii() or not key.isprintable():
        raise InvalidInput(f"Idempotency-Key must be 1..{MAX_BATCH_ID_CHARS} printable ASCII characters")
    return key


def batch_record(raw: Any, batch_id: str | None = None) -> bytes:
    """The batch as the engine takes it (its log record); the engine validates it."""
    try:
        return encode_batch(raw, batch_id)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InvalidEdit(f"edits: cannot be encoded as an edit batch: {exc}") from None


@router.post("/worlds/{world_id}/edits", openapi_extra=request_body(EditsBody),
             summary="Apply one edit batch atomically; answers the version it produced")
async def post_edits(request: Request, world_id: str) -> Response:
    settings = request.app.state.settings
    batch_id = batch_id_of(request)
    raw = _edits_wire(await decode_body(request), settings.max_ops_per_batch)
    version = await engine_of(request).apply_edits(world_id, batch_record(raw, batch_id), access_of(request))
    return respond(request, {"version": version})


def _vec3(text: str | None, name: str) -> tuple[int, int, int] | None:
    if text is None:
        return None
    try:
        x, y, z = text.split(",")
        return int(x), int(y), int(z)
    except ValueError:
        raise InvalidInput(f"{name} must be three integers 'x,y,z', got {short(text)}") from None


def box_param(lo: str | None, hi: str | None) -> Box | None:
    lo3, hi3 = _vec3(lo, "min"), _vec3(hi, "max")
    if lo3 is None and hi3 is None:
        return None
    if lo3 is None or hi3 is None:
        raise InvalidInput("give both min and max, or neither for the whole world")
    return Box(lo3, hi3)


def _array_response(request: Request, result: Any, dtype: str) -> Response:
    """The read as msgpack {origin, shape, dtype, version, data}, raw bytes, or JSON with base64 data."""
    array = result.array
    facts = {"origin": list(result.origin), "shape": list(array.shape), "dtype": dtype, "version": result.version,
             **({"content": result.content} if result.content else {})}
    accept = header(request, b"accept") or ""
    if OCTET in accept:
        headers = [(b"x-sdf-origin", ",".join(map(str, facts["origin"])).encode()),
                   (b"x-sdf-shape", ",".join(map(str, facts["shape"])).encode()),
                   (b"x-sdf-dtype", dtype.encode()), (b"x-sdf-version", str(result.version).encode()),
                   *([(b"x-sdf-content", result.content.encode())] if result.content else [])]
        body = np.ascontiguousarray(array, dtype=LITTLE_ENDIAN[dtype]).tobytes()
        response = Encoded(body, OCTET, headers=headers)
    elif "application/json" in accept and MSGPACK not in accept:
        facts["data"] = base64.b64encode(array.tobytes()).decode()
        facts["encoding"] = "base64"
        return respond(request, facts)
    else:
        facts["data"] = array.astype(LITTLE_ENDIAN[dtype], copy=False).tobytes()
        response = Encoded(wire.encode(facts), MSGPACK)
    request.app.state.metrics.bytes_out.inc(len(response.body))
    return response


@router.get("/worlds/{world_id}/field", summary="Read the field of a box (max exclusive)",
            responses={200: {"content": {OCTET: {}}}})
async def read_field(request: Request, world_id: str,
                     min: str | None = Query(None, description="x,y,z (inclusive); default 0,0,0"),
                     max: str | None = Query(None, description="x,y,z (exclusive); default the world size"),
                     format: str = Query("distance", pattern="^(distance|packed)$",
                                         description="distance: uint8 (int16 signed, float32 Euclidean); "
                                         "packed: uint16, (distance << 8) | colour (Manhattan) or the squared "
                                         "distance (Euclidean): the answer's content says which"),
                     min_version: int = Query(0, ge=0, description="wait until the field reflects this version")
                     ) -> Response:
    return await field_response(request, world_id, box_param(min, max), format, min_version)


async def field_response(request: Request, world_id: str, box: Box | None, format: str,
                         min_version: int) -> Response:
    """The field read once its parameters are checked."""
    result = await engine_of(request).read(world_id, format, box, min_version, access_of(request))
    return _array_response(request, result, result.array.dtype.name)


@router.get("/worlds/{world_id}/voxels", summary="Read the voxels of a box (max exclusive)",
            responses={200: {"content": {OCTET: {}}}})
async def read_voxels(request: Request, world_id: str,
                      min: str | None = Query(None, description="x,y,z (inclusive)"),
                      max: str | None = Query(None, description="x,y,z (exclusive)"),
                      min_version: int = Query(0, ge=0, description="wait until the voxels reflect this version")
                      ) -> Response:
    result = await engine_of(request).read(world_id, "voxels", box_param(min, max), min_version,
                                           access_of(request))
    return _array_response(request, result, "uint8")


@router.post("/worlds/{world_id}/query", openapi_extra=request_body(QueryBody),
             summary="Collision and navigation queries: points, spheres or rays, in world units")
async def query(request: Request, world_id: str,
                min_version: int = Query(0, ge=0, description="wait until the field reflects this version")
                ) -> Response:
    return await query_response(request, world_id, min_version)


QUERY_COLUMNS = {"points": 3, "spheres": 4, "rays": 7}


async def query_response(request: Request, world_id: str, min_version: int) -> Response:
    """A points, spheres or rays query once min_version is checked; the engine checks the rows'
    values (engine/query.py) and answers in world units. ``Server-Timing: app;dur=<ms>`` says
    how long this took, from here (before the body is read) to the response made."""
    started = time.perf_counter()
    kind, rows = query_rows(await decode_body(request), request.app.state.settings.max_query_points)
    result = await engine_of(request).query(world_id, rows, min_version, access_of(request), kind)
    answer = {"version": result.version, **result.arrays}
    if "hits" in answer and wants_msgpack(request):
        answer["hits"] = answer["hits"].astype(np.uint8)  # blobs carry no booleans
    return respond(request, answer, timed_from=started)


def query_rows(body: Any, limit: int) -> tuple[str, np.ndarray]:
    """The one kind a query body asks and its rows (a blob, or lists checked by QueryBody)."""
    kinds = [k for k in QUERY_COLUMNS if isinstance(body, dict) and k in body]
    if not isinstance(body, dict) or len(kinds) != 1 or len(body) != 1:
        extra = sorted(set(body) - set(QUERY_COLUMNS)) if isinstance(body, dict) else []
        raise InvalidInput(f"unknown field {short(extra[0])} in a query body" if extra else
                           "a query body holds exactly one of 'points', 'spheres' or 'rays'")
    kind, raw = kinds[0], body[kinds[0]]
    if isinstance(raw, list) and len(raw) > limit:
        raise TooLarge(f"{len(raw)} {kind} in one query; the limit is {limit} (max_query_points)")
    if wire.is_blob(raw):
        rows = wire.unpack_array(raw, kind)
    else:
        listed = getattr(QueryBody.model_validate(body), kind)
        if listed is None:  # {"points": null}: the models allow null for the kinds not asked
            raise InvalidInput(f"{kind} must be a list of rows or an array blob, got null")
        rows = np.array(listed, dtype=np.float64).reshape(-1, QUERY_COLUMNS[kind])
    if rows.ndim != 2 or rows.shape[1] != QUERY_COLUMNS[kind] or rows.dtype.kind not in "iuf":
        raise InvalidInput(f"{kind} must be an (N, {QUERY_COLUMNS[kind]}) numeric array, "
                           f"got {rows.dtype} {list(rows.shape)}")
    if len(rows) > limit:
        raise TooLarge(f"{len(rows)} {kind} in one query; the limit is {limit} (max_query_points)")
    if len(rows) == 0:
        raise InvalidInput(f"{kind} must not be empty")
    return kind, rows
