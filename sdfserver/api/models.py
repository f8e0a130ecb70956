"""Request models for the JSON boundary (pydantic lives here and nowhere deeper)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, StrictBool, StrictFloat, StrictInt, StrictStr

from sdfserver.world_config import MAX_SIDE_VOX, MAX_SPARSE_SIDE_XZ_VOX

# Every number is bounded here, at the door: what passes fits the log, msgpack and the device.
INT32_MIN, INT32_MAX = -(1 << 31), (1 << 31) - 1
Int32 = Annotated[StrictInt, Field(ge=INT32_MIN, le=INT32_MAX)]
Int3 = Annotated[list[Int32], Field(min_length=3, max_length=3, description="[x, y, z]")]
# Dense worlds stop at MAX_SIDE_VOX a side, sparse ones further (WorldConfig says which, with a 422).
Side = Annotated[StrictInt, Field(ge=1, le=MAX_SPARSE_SIDE_XZ_VOX)]
ChunkCount = Annotated[StrictInt, Field(ge=1, le=INT32_MAX)]
Point3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]
Algorithm = Annotated[StrictStr, Field(description="exact, brute, fim, jfa, jfa+1, jfa+2 or jfa_fim")]
Borders = Annotated[StrictStr, Field(description="exact (default) or padded: each chunk computed alone, everything outside it solid (the dissertation's §4.2.1; brute, fim, jfa, jfa+1, jfa+2, jfa_fim)")]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class FocusBody(Strict):
    center: Int3 = Field(description="Focus centre, in chunks.")
    size: Annotated[list[ChunkCount], Field(min_length=3, max_length=3)] = Field(
        description="Focus extent, in chunks.")


Number = Annotated[FiniteFloat, Field(ge=0, le=1 << 16)]


class GenerateBody(Strict):
    kind: Literal["terrain"] = Field(description="terrain: a heightmap with overhangs, caves and colours.")
    seed: Annotated[StrictInt, Field(ge=0, le=(1 << 32) - 1)] = 0
    base: Number | None = Field(None, description="Height the surface rolls around (default 0.4 of the world's).")
    amplitude: Number | None = Field(None, description="The surface lies within base ± amplitude (default 0.15 of the height).")
    overhang: Number = Field(8.0, description="How far 3-D noise moves the surface up or down, 0..64.")
    cave_depth: Number = Field(40.0, description="Caves lie at most this far below the surface, 0..256.")


Metric = Annotated[StrictStr, Field(description="manhattan (default): the capped L1 distance, packed with the colour; "
                                    "euclidean: the exact distance between voxel centres (docs/algorithms.md)")]
# Strict: "true", 1 or "1.5" are refused naming the field, not coerced into a bool or a number.
Signed = Annotated[StrictBool, Field(description="true: solids carry minus their distance to the nearest air voxel")]
VoxelSize = Annotated[StrictFloat, Field(description="World units per voxel (queries answer in world units); "
                                                     "finite, > 0")]
Origin = Annotated[list[StrictFloat], Field(min_length=3, max_length=3,
                                            description="World-unit position of voxel (0, 0, 0)'s low corner")]
Palette = Annotated[list[list[StrictInt]], Field(
    description="255 [r, g, b] colours (0..255): voxel value v is drawn as palette[v - 1]; default RGB332")]


class FieldOptions(Strict):
    """What a world's field holds and where it lies in world units (create and PATCH). Values are
    checked by WorldConfig.validated, which names the field in its 422."""

    metric: Metric | None = None
    signed: Signed | None = None
    voxel_size: VoxelSize | None = None
    origin: Origin | None = None
    palette: Palette | None = None


class CreateWorldBody(FieldOptions):
    size: Annotated[list[Side], Field(min_length=3, max_length=3)] = Field(
        description="World size in voxels, each a multiple of chunk_size.")
    chunk_size: StrictInt = Field(16, ge=8, le=128, description="Chunk side in voxels: 8, 16, 32, 64 or 128.")
    max_distance: StrictInt = Field(255, ge=1, le=255, description="Distance cap, 1..255.")
    algorithm: Algorithm = "exact"
    lod_algorithm: Algorithm = "jfa"
    focus: FocusBody | None = Field(None, description="Where `algorithm` runs; elsewhere `lod_algorithm`.")
    borders: Borders = "exact"
    storage: Literal["dense", "sparse"] = Field(
        "dense", description=f"dense: every voxel on the device (sides up to {MAX_SIDE_VOX}). sparse: only bricks "
        "that are neither all air at the cap nor all one solid colour (sides up to 65536 along x and z, 4096 along y).")
    generate: GenerateBody | None = Field(None, description="Sparse worlds only: start as this terrain, not as air.")


class PatchWorldBody(FieldOptions):
    algorithm: Algorithm | None = None
    lod_algorithm: Algorithm | None = None
    borders: Borders | None = None
    max_distance: Annotated[StrictInt, Field(ge=1, le=255)] | None = None
    focus: FocusBody | None = Field(None, description="null removes the focus; leave it out to keep it.")


class MoveWorldBody(Strict):
    engine: Annotated[StrictInt, Field(ge=0, le=255, description="The engine (GET /v1/engines) to move the world to.")]


class EditOp(BaseModel):
    """One operation: {op: voxels, voxels} | {op: box, min, max, colour} | {op: sphere, center, radius, colour}."""

    op: Literal["voxels", "box", "sphere"]
    voxels: Any = Field(None, description="N x 4 uint16 blob (msgpack) or [[x, y, z, colour], ...].")
    min: list[int] | None = None
    max: list[int] | None = Field(None, description="Box corner, exclusive.")
    center: list[float] | None = None
    radius: float | None = None
    colour: int | None = Field(None, description="0 erases; 1..255 is an index into the world's palette "
                                                 "(RGB332 unless the world has its own).")


class EditsBody(BaseModel):
    """Documentation only: edit bodies are checked by sdfserver.edits.parse_edits."""

    edits: list[EditOp]


Sphere4 = Annotated[list[FiniteFloat], Field(min_length=4, max_length=4)]
Ray7 = Annotated[list[FiniteFloat], Field(min_length=7, max_length=7)]


class QueryBody(Strict):
    """Exactly one of points, spheres or rays (world units; each an N x 3, 4 or 7 float32 blob in
    msgpack), at most max_query_points rows."""

    points: list[Point3] | None = Field(None, description="[[x, y, z], ...]: distance, gradient and colour at each.")
    spheres: list[Sphere4] | None = Field(None, description="[[x, y, z, r], ...]: clearance and the way out of each.")
    rays: list[Ray7] | None = Field(None, description="[[ox, oy, oz, dx, dy, dz, max_length], ...]: each one's first "
                                                      "solid voxel.")


# Schemas that request bodies refer to; create_app adds them to the OpenAPI components.
SCHEMAS: dict[str, Any] = {}


def request_body(model: type[BaseModel]) -> dict[str, Any]:
    """openapi_extra for a route that reads its body itself (JSON or msgpack)."""
    schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
    SCHEMAS.update(schema.pop("$defs", {}))
    SCHEMAS[model.__name__] = schema
    content = {"schema": {"$ref": f"#/components/schemas/{model.__name__}"}}
    return {"requestBody": {"required": True, "content": {"application/json": content,
                                                          "application/msgpack": content}}}
