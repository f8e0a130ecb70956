"""Edit operations and their validation.

An edit batch is a list of operations applied in order: explicit voxels,
axis-aligned boxes (half-open, ``min <= p < max``) and spheres (voxel ``p``
is inside when ``|p - center| <= radius``). Colour 0 erases. Brushes (boxes
and spheres) are clipped to the world; explicit voxels out of bounds reject
the whole batch. Everything is checked here, on the host, before the device
is touched: a batch applies whole or not at all.

Two kinds of check. ``parse_edits`` checks structure: types, and numbers that the log, NumPy
and the device can hold (integers within int64, finite numbers). ``validate_batch`` checks
against ``EditLimits``: counts, the brush radius and the coordinate range a client may send.
Replaying the log at start-up uses ``REPLAY_LIMITS``, so what was once accepted is applied
whatever today's limits are.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Integral
from typing import Annotated, Any, Union

import msgspec
import numpy as np

from sdfserver import incoming
from sdfserver.errors import InvalidEdit, TooLarge
from sdfserver.geometry import Box

Vec3 = tuple[int, int, int]
INT64_MIN, INT64_MAX = -(1 << 63), (1 << 63) - 1
MAX_COORDINATE_VOX = (1 << 31) - 1  # box corners and sphere centres: int32, whatever the world


@dataclass(frozen=True)
class EditLimits:
    max_ops_per_batch: int = 1024
    max_voxels_per_batch: int = 1 << 20
    max_brush_radius_vox: float = 256.0
    max_coordinate_vox: float = MAX_COORDINATE_VOX  # |box corner|, |sphere centre|
    # the voxels a batch's boxes and spheres cover (clipped to the world), summed over its edits;
    # a batch may always cover the world once, however small this is
    max_brush_voxels_per_batch: float = 1 << 30


# What replay admits: every batch that parses. Limits guard what comes in, not what was
# already accepted and logged.
REPLAY_LIMITS = EditLimits(max_ops_per_batch=1 << 62, max_voxels_per_batch=1 << 62,
                           max_brush_radius_vox=math.inf, max_coordinate_vox=math.inf,
                           max_brush_voxels_per_batch=math.inf)


@dataclass(frozen=True)
class VoxelsEdit:
    voxels: np.ndarray  # (N, 4) int64: x, y, z, colour


# Brushes are msgspec structs, so that a batch of them decodes from its log record in one call
# (``decode_brushes``); the constraints are the ones parse_edit checks.
_Colour = Annotated[int, msgspec.Meta(ge=0, le=255)]
_Int64 = Annotated[int, msgspec.Meta(ge=INT64_MIN, le=INT64_MAX)]


class BoxEdit(msgspec.Struct, frozen=True, tag="box", tag_field="op"):
    min: tuple[_Int64, _Int64, _Int64]
    max: tuple[_Int64, _Int64, _Int64]
    colour: _Colour


class SphereEdit(msgspec.Struct, frozen=True, tag="sphere", tag_field="op"):
    center: tuple[float, float, float]
    radius: float
    colour: _Colour


Edit = Union[VoxelsEdit, BoxEdit, SphereEdit]


class _BatchWithId(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    batch_id: str
    edits: list[Union[BoxEdit, SphereEdit]]


_BRUSHES = msgspec.msgpack.Decoder(Union[list[Union[BoxEdit, SphereEdit]], _BatchWithId])


def decode_brushes(payload: bytes) -> tuple[list[Edit], str | None] | None:
    """A log record's edits and batch id where every edit is a box or a sphere that parse_edit
    would take as it is (the same objects); None for anything else (voxels, a value out of range,
    a malformed record), which ``codec.decode_batch`` and ``parse_edits`` then decode, or refuse
    with their messages."""
    try:
        decoded = _BRUSHES.decode(payload)
    except (msgspec.DecodeError, msgspec.ValidationError):
        return None
    edits, batch_id = (decoded, None) if type(decoded) is list else (decoded.edits, decoded.batch_id)
    for e in edits:
        if type(e) is SphereEdit:
            (x, y, z), r = e.center, e.radius
            if not (r - r == 0.0 and x - x == 0.0 and y - y == 0.0 and z - z == 0.0):  # NaN or infinite
                return None
    return edits, batch_id


def _colour(value: Any, where: str) -> int:
    if type(value) is int and 0 <= value <= 255:  # the common case, no ABC checks
        return value
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise InvalidEdit(f"{where}: colour must be an integer 0..255, got {incoming.short(value)}")
    if not 0 <= int(value) <= 255:
        raise InvalidEdit(f"{where}: colour must be 0..255, got {value}")
    return int(value)


def _int3(value: Any, where: str) -> Vec3:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise InvalidEdit(f"{where}: expected three integers [x, y, z], got {incoming.short(value)}")
    x, y, z = value
    if type(x) is int and type(y) is int and type(z) is int and (  # the common case, no ABC checks
            INT64_MIN <= x <= INT64_MAX and INT64_MIN <= y <= INT64_MAX and INT64_MIN <= z <= INT64_MAX):
        return x, y, z
    for v in value:
        if isinstance(v, bool) or not isinstance(v, Integral):
            raise InvalidEdit(f"{where}: expected integers, got {incoming.short(v)}")
        if not INT64_MIN <= v <= INT64_MAX:
            raise InvalidEdit(f"{where}: {incoming.short(v)} is out of range (coordinates are "
                              f"-{MAX_COORDINATE_VOX + 1}..{MAX_COORDINATE_VOX})")
    return tuple(int(v) for v in value)


def finite(value: Any, where: str) -> float:
    return incoming.finite(value, where, InvalidEdit)


def _real3(value: Any, where: str) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise InvalidEdit(f"{where}: expected three numbers [x, y, z], got {incoming.short(value)}")
    return tuple(finite(v, where) for v in value)


def _voxel_array(value: Any, where: str) -> np.ndarray:
    """Accept an (N, 4) integer array or a list of [x, y, z, colour] lists."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "iu":
            raise InvalidEdit(f"{where}: voxel array must be integer, got {value.dtype}")
        array = value
    elif isinstance(value, (list, tuple)):
        for row in value:
            if not isinstance(row, (list, tuple)) or len(row) != 4 or any(
                isinstance(v, bool) or not isinstance(v, Integral) for v in row
            ):
                raise InvalidEdit(f"{where}: each voxel must be [x, y, z, colour] integers, got {incoming.short(row)}")
        try:
            array = np.asarray(value, dtype=np.int64).reshape(-1, 4)
        except OverflowError:
            raise InvalidEdit(f"{where}: a voxel value is out of range (coordinates lie in the world, "
                              "colours are 0..255)") from None
    else:
        raise InvalidEdit(f"{where}: voxels must be an N x 4 array or a list, got {type(value).__name__}")
    if array.ndim != 2 or array.shape[1] != 4:
        raise InvalidEdit(f"{where}: voxel array must have shape (N, 4), got {array.shape}")
    return array.astype(np.int64, copy=False)


def parse_edit(raw: Any, index: int) -> Edit:
    """One operation from its wire form (a dict with ``op``)."""
    if type(raw) is dict and raw.get("op") == "sphere":  # the common brush: no error texts built
        center, radius, colour = raw.get("center"), raw.get("radius"), raw.get("colour")
        if type(center) is list and len(center) == 3 and type(radius) is float and type(colour) is int:
            x, y, z = center
            if (type(x) is float and type(y) is float and type(z) is float and 0 <= colour <= 255
                    and radius - radius == 0.0 and x - x == 0.0 and y - y == 0.0 and z - z == 0.0):  # finite
                return SphereEdit((x, y, z), radius, colour)
    where = f"edits[{index}]"
    if not isinstance(raw, dict):
        raise InvalidEdit(f"{where}: expected an object with 'op', got {type(raw).__name__}")
    op = raw.get("op")
    try:
        if op == "voxels":
            return VoxelsEdit(_voxel_array(raw["voxels"], where))
        if op == "box":
            return BoxEdit(_int3(raw["min"], where + ".min"), _int3(raw["max"], where + ".max"),
                           _colour(raw["colour"], where))
        if op == "sphere":
            radius = finite(raw["radius"], where + ".radius")
            return SphereEdit(_real3(raw["center"], where + ".center"), radius, _colour(raw["colour"], where))
    except KeyError as exc:
        raise InvalidEdit(f"{where}: missing field {exc.args[0]!r} for op {incoming.short(op)}") from None
    raise InvalidEdit(f"{where}: unknown op {incoming.short(op)}; expected 'voxels', 'box' or 'sphere'")


def parse_edits(raw: Any) -> list[Edit]:
    if not isinstance(raw, (list, tuple)):
        raise InvalidEdit(f"edits must be a list, got {type(raw).__name__}")
    return [parse_edit(item, i) for i, item in enumerate(raw)]


def validate_batch(edits: list[Edit], dims: Vec3, limits: EditLimits) -> None:
    """Raise InvalidEdit / TooLarge for anything that cannot apply; change nothing."""
    if not edits:
        raise InvalidEdit("empty edit batch")
    if len(edits) > limits.max_ops_per_batch:
        raise TooLarge(f"{len(edits)} operations in one batch; the limit is {limits.max_ops_per_batch}")
    # Brushes are checked in plain Python, numpy only for voxel lists: this runs on the engine
    # thread for every batch, and most batches are one brush.
    voxel_lists = [e for e in edits if type(e) is VoxelsEdit]
    if voxel_lists:
        total_voxels = sum(len(e.voxels) for e in voxel_lists)
        if total_voxels > limits.max_voxels_per_batch:
            raise TooLarge(f"{total_voxels} voxels in one batch; the limit is {limits.max_voxels_per_batch}")
        upper = np.array(dims, dtype=np.int64)
    for i, e in enumerate(edits):
        kind = type(e)
        if kind is SphereEdit:
            if not 0 <= e.radius <= limits.max_brush_radius_vox:
                raise InvalidEdit(
                    f"edits[{i}]: radius must be 0..{limits.max_brush_radius_vox:g}, got {e.radius:g}"
                )
            _check_colour(e.colour, i)
            _check_coordinates(e.center, limits, i, "center")
        elif kind is BoxEdit:
            (x0, y0, z0), (x1, y1, z1) = e.min, e.max
            if x0 > x1 or y0 > y1 or z0 > z1:
                raise InvalidEdit(f"edits[{i}]: box min {list(e.min)} exceeds max {list(e.max)}")
            _check_colour(e.colour, i)
            _check_coordinates(e.min, limits, i, "min")
            _check_coordinates(e.max, limits, i, "max")
        elif kind is VoxelsEdit:
            where = f"edits[{i}]"
            if len(e.voxels) == 0:
                raise InvalidEdit(f"{where}: empty voxel list")
            xyz, colour = e.voxels[:, :3], e.voxels[:, 3]
            bad = np.flatnonzero(((xyz < 0) | (xyz >= upper)).any(axis=1))
            if bad.size:
                raise InvalidEdit(
                    f"{where}: voxel {e.voxels[bad[0], :3].tolist()} is outside the world "
                    f"{list(dims)} ({bad.size} out of bounds)"
                )
            if ((colour < 0) | (colour > 255)).any():
                raise InvalidEdit(f"{where}: colours must be 0..255")
        else:
            raise InvalidEdit(f"edits[{i}]: not an edit: {e!r}")
    _check_brush_voxels(edits, dims, limits)


def plan_brushes(edits: list[Edit], dims: Vec3, limits: EditLimits) -> list[list[Box]] | None:
    """``validate_batch`` and each edit's ``edit_bounds`` in one pass, for a batch of boxes and
    spheres that passes every check; None for any other batch (``validate_batch`` then says what
    is wrong). Runs on the engine thread for every batch."""
    if not edits or len(edits) > limits.max_ops_per_batch:
        return None
    top = limits.max_coordinate_vox
    bottom, max_radius = -top - 1, limits.max_brush_radius_vox
    bounds, total = [], 0
    for e in edits:
        kind = type(e)
        if kind is not SphereEdit and kind is not BoxEdit:
            return None
        colour = e.colour
        if type(colour) is not int or not 0 <= colour <= 255:
            return None
        if kind is SphereEdit:
            (cx, cy, cz), r = e.center, e.radius
            if not (0 <= r <= max_radius and bottom <= cx <= top and bottom <= cy <= top and bottom <= cz <= top):
                return None
        else:
            (x0, y0, z0), (x1, y1, z1) = e.min, e.max
            if (x0 > x1 or y0 > y1 or z0 > z1 or not (bottom <= x0 <= top and bottom <= y0 <= top
                                                      and bottom <= z0 <= top and bottom <= x1 <= top
                                                      and bottom <= y1 <= top and bottom <= z1 <= top)):
                return None
        boxes = _brush_bounds(e, dims)
        bounds.append(boxes)
        if boxes:
            (x0, y0, z0), (x1, y1, z1) = boxes[0].lo, boxes[0].hi
            total += (x1 - x0) * (y1 - y0) * (z1 - z0)
    if total > max(limits.max_brush_voxels_per_batch, dims[0] * dims[1] * dims[2]):
        return None
    return bounds


def _check_brush_voxels(edits: list[Edit], dims: Vec3, limits: EditLimits) -> None:
    """TooLarge when the batch's boxes and spheres cover more voxels, summed, than the limit (or
    the world, if it is larger): each of those voxels costs the device a visit, and a batch of
    many large brushes would hold the engine for as long as they take."""
    world = dims[0] * dims[1] * dims[2]
    allowed = max(limits.max_brush_voxels_per_batch, world)
    brushes = [e for e in edits if type(e) is not VoxelsEdit]
    if len(brushes) * world <= allowed:  # however large each is: most batches stop here
        return
    total = 0
    for e in brushes:
        for box in edit_bounds(e, dims, 1):
            total += box.volume
    if total > allowed:
        raise TooLarge(f"the batch's {len(brushes)} boxes and spheres cover {total:,} voxels together (clipped "
                       f"to the world); the limit is {int(allowed):,} (max_brush_voxels_per_batch, or the "
                       f"world's voxels if more)")


def _check_coordinates(values: tuple, limits: EditLimits, index: int, field: str) -> None:
    bound = limits.max_coordinate_vox
    if not (-bound - 1 <= values[0] <= bound and -bound - 1 <= values[1] <= bound
            and -bound - 1 <= values[2] <= bound):
        raise InvalidEdit(f"edits[{index}].{field}: {list(values)} is out of range (coordinates are "
                          f"{-bound - 1:.0f}..{bound:.0f})")


def _check_colour(value: Any, index: int) -> None:
    if type(value) is not int or not 0 <= value <= 255:  # the common case without the ABC checks
        _colour(value, f"edits[{index}]")


def _brush_bounds(edit: BoxEdit | SphereEdit, dims: Vec3) -> list[Box]:
    """A box's or a sphere's world-clipped box, in plain ints (one Box made, not three); empty
    where it misses the world."""
    if type(edit) is SphereEdit:
        (cx, cy, cz), r = edit.center, edit.radius
        x0, y0, z0 = math.ceil(cx - r), math.ceil(cy - r), math.ceil(cz - r)
        x1, y1, z1 = math.floor(cx + r) + 1, math.floor(cy + r) + 1, math.floor(cz + r) + 1
    else:
        (x0, y0, z0), (x1, y1, z1) = edit.min, edit.max
    sx, sy, sz = dims
    lo = (max(x0, 0), max(y0, 0), max(z0, 0))
    hi = (min(x1, sx), min(y1, sy), min(z1, sz))
    if hi[0] <= lo[0] or hi[1] <= lo[1] or hi[2] <= lo[2]:
        return []
    return [Box(lo, hi)]


def edit_bounds(edit: Edit, dims: Vec3, chunk_size_vox: int) -> list[Box]:
    """World-clipped boxes covering what an edit may change (empty list: nothing).

    Explicit voxels give one tight box per touched chunk, so scattered voxels
    do not turn into one world-sized box.
    """
    kind = type(edit)
    if kind is SphereEdit or kind is BoxEdit:
        return _brush_bounds(edit, dims)
    xyz = edit.voxels[:, :3]
    _, group = np.unique(xyz // chunk_size_vox, axis=0, return_inverse=True)
    group = group.reshape(-1)
    count = int(group.max()) + 1
    lo = np.full((count, 3), np.iinfo(np.int64).max, dtype=np.int64)
    hi = np.full((count, 3), np.iinfo(np.int64).min, dtype=np.int64)
    np.minimum.at(lo, group, xyz)
    np.maximum.at(hi, group, xyz + 1)
    return [Box(tuple(map(int, a)), tuple(map(int, b))) for a, b in zip(lo, hi)]


def writes(edit: Edit) -> tuple[bool, bool]:
    """Whether ``edit`` may write air (colour 0) anywhere, and whether it may write a solid."""
    if isinstance(edit, VoxelsEdit):
        air = edit.voxels[:, 3] == 0
        return bool(air.any()), not bool(air.all())
    return edit.colour == 0, edit.colour != 0
