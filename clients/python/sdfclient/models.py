"""What the client returns: plain dataclasses holding the server's answers.

Arrays are NumPy arrays in the server's layout, ``(z, y, x)``; positions and
sizes are ``(x, y, z)``.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

Vec3 = tuple[int, int, int]


def _vec3(value: Any) -> Vec3 | None:
    return None if value is None else tuple(int(v) for v in value)


@dataclass(frozen=True)
class Focus:
    """The box of chunks computed with the world's algorithm (the rest uses the LOD one)."""

    center: Vec3
    size: Vec3

    def to_wire(self) -> dict:
        return {"center": list(self.center), "size": list(self.size)}

    @classmethod
    def from_wire(cls, raw: Any) -> "Focus | None":
        if raw is None:
            return None
        return cls(_vec3(raw["center"]), _vec3(raw["size"]))


@dataclass(frozen=True)
class WorldInfo:
    """A world's description as the server gives it."""

    id: str
    size: Vec3
    chunk_size: int
    max_distance: int
    algorithm: str
    version: int
    field_version: int = 0
    focus: Focus | None = None
    dirty_chunks: int = 0
    last_recompute_ms: float | None = None
    metric: str = "manhattan"
    signed: bool = False
    voxel_size: float = 1.0
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    storage: str = "dense"  # or "sparse": only the bricks near surfaces on the device
    device_bytes: int = 0
    # What the server says about the answer besides the world: an import into a sparse world
    # that holds more device memory than the dense one would, for one
    warnings: tuple[str, ...] = ()
    raw: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def from_wire(cls, raw: dict) -> "WorldInfo":
        last = raw.get("last_recompute_ms")
        return cls(
            id=str(raw["id"]),
            size=_vec3(raw["size"]),
            chunk_size=int(raw["chunk_size"]),
            max_distance=int(raw["max_distance"]),
            algorithm=str(raw["algorithm"]),
            version=int(raw.get("version", 0)),
            field_version=int(raw.get("field_version", 0)),
            focus=Focus.from_wire(raw.get("focus")),
            dirty_chunks=int(raw.get("dirty_chunks", raw.get("dirty_chunk_count", 0)) or 0),
            last_recompute_ms=None if last is None else float(last),
            metric=str(raw.get("metric", "manhattan")),
            signed=bool(raw.get("signed", False)),
            voxel_size=float(raw.get("voxel_size", 1.0)),
            origin=tuple(float(v) for v in raw.get("origin", (0.0, 0.0, 0.0))),
            storage=str(raw.get("storage", "dense")),
            device_bytes=int(raw.get("device_bytes", 0) or 0),
            warnings=tuple(str(w) for w in raw.get("warnings", ()) or ()),
            raw=dict(raw),
        )


@dataclass(frozen=True)
class Block:
    """A box of the field or of the voxels: ``data`` has shape (z, y, x)."""

    origin: Vec3  # (x, y, z) of data[0, 0, 0]
    version: int  # the edit version this block reflects
    data: np.ndarray  # in the dtype the answer named
    format: str = "distance"  # distance | packed | voxels
    # What the values are, as the answer says: "distance", or for packed blocks "distance_colour"
    # (Manhattan worlds) or "squared_distance" (Euclidean ones); "" where the server did not say.
    content: str = ""

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.data.shape)

    @property
    def distance(self) -> np.ndarray:
        """Distances in voxels. A distance block as read: uint8, int16 (a signed Manhattan world)
        or float32 (a Euclidean world). A packed block's magnitudes: the high byte (uint8) of a
        Manhattan world's values, the square root (float32) of a Euclidean world's; the sign of a
        signed world's solids is not in them (read format='distance')."""
        if self.format != "packed":
            return self.data
        if self.content == "squared_distance":
            return np.sqrt(self.data, dtype=np.float32)
        return (self.data >> 8).astype(np.uint8)

    @property
    def colour(self) -> np.ndarray:
        """The low byte of a Manhattan world's packed field: the voxel's value, an index into the
        world's palette (RGB332 unless the world has its own)."""
        if self.format != "packed":
            raise ValueError(f"a {self.format} block has no colour; read with format='packed'")
        if self.content == "squared_distance":
            raise ValueError("a Euclidean world's packed field holds squared distances, no colour; "
                             "read the voxels (read_voxels)")
        return (self.data & 0xFF).astype(np.uint8)


@dataclass(frozen=True)
class QueryResult:
    """The field at points (world units): distances interpolated between voxel centres, the
    interpolant's gradient, and the value of the voxel holding each point."""

    distances: np.ndarray  # (N,) float32 world units; negative inside solids of a signed world
    gradients: np.ndarray  # (N, 3) float32 d(distance)/d(world unit), x y z; not normalised
    version: int
    colours: np.ndarray | None = None  # (N,) uint8 voxel values, 0 in air


@dataclass(frozen=True)
class SphereResult:
    """Spheres against the field: how far each is from touching, and the way out."""

    clearances: np.ndarray  # (N,) float32 world units: the distance at the centre minus the radius
    directions: np.ndarray  # (N, 3) float32 unit vectors out of collision; zero where the field is flat
    version: int


@dataclass(frozen=True)
class RayResult:
    """Each ray's first solid voxel within its max length."""

    hits: np.ndarray  # (N,) bool
    distances: np.ndarray  # (N,) float32 world units along the normalised direction (a miss: max_length)
    normals: np.ndarray  # (N, 3) float32 the entered face's normal (zero: a miss, or a ray starting in a solid)
    colours: np.ndarray  # (N,) uint8 the voxel value hit (0: a miss)
    voxels: np.ndarray  # (N, 3) int32 the voxel hit (-1, -1, -1: a miss)
    version: int


@dataclass(frozen=True)
class ChunkUpdate:
    """One changed chunk from the stream."""

    origin: Vec3
    data: np.ndarray  # (z, y, x)


@dataclass(frozen=True)
class StreamMessage:
    """A frame from the stream: an acknowledgement or a set of changed chunks."""

    type: str  # "ack" | "chunks" | "subscribed" | "error" | anything the server adds
    version: int | None = None
    chunks: list[ChunkUpdate] = field(default_factory=list)
    raw: dict = field(default_factory=dict, repr=False)


@dataclass(frozen=True)
class Exported:
    """A world exported as a file (``GET .../export``)."""

    format: str  # snapshot | npy | vox
    version: int  # the edit version the file holds (X-Sdf-Version)
    data: bytes
    filename: str = ""  # the server's suggestion, e.g. "<id>.npy"

    @property
    def array(self) -> np.ndarray:
        """The voxels of an ``npy`` export: uint8 RGB332, shape (z, y, x); loaded without pickle."""
        if self.format != "npy":
            raise ValueError(f"a {self.format} export is not an array; export with format='npy'")
        return np.load(io.BytesIO(self.data), allow_pickle=False)

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_bytes(self.data)
        return path


@dataclass(frozen=True)
class Camera:
    """A view for ``render``/``pick``, in voxel units, y up.

    Either ``target`` (look at that point) or ``yaw_deg``/``pitch_deg`` (yaw 0, pitch 0 looks
    along -z; yaw turns toward +x; pitch -90 looks straight down).
    """

    position: tuple[float, float, float]
    target: tuple[float, float, float] | None = None
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    fov_y_deg: float = 60.0
    width: int = 640
    height: int = 480

    @classmethod
    def look_at(cls, position: Sequence[float], target: Sequence[float], **kwargs: Any) -> "Camera":
        return cls(tuple(float(v) for v in position), target=tuple(float(v) for v in target), **kwargs)

    def to_wire(self) -> dict:
        wire: dict[str, Any] = {"position": [float(v) for v in self.position], "fov_y_deg": float(self.fov_y_deg),
                                "width": int(self.width), "height": int(self.height)}
        if self.target is not None:
            wire["target"] = [float(v) for v in self.target]
        else:
            wire["yaw_deg"], wire["pitch_deg"] = float(self.yaw_deg), float(self.pitch_deg)
        return wire


@dataclass(frozen=True)
class Frame:
    """A rendered image (``POST .../render``)."""

    format: str  # png | jpeg | rgba
    data: bytes  # the encoded image; for rgba, height * width * 4 bytes, rows top first
    field_version: int  # the field version drawn (X-Field-Version)
    width: int
    height: int
    render_ms: float | None = None  # the kernel's device time

    @property
    def pixels(self) -> np.ndarray:
        """(height, width, 4) uint8 RGBA; PNG and JPEG are decoded with Pillow."""
        if self.format == "rgba":
            return np.frombuffer(self.data, dtype=np.uint8).reshape(self.height, self.width, 4)
        try:
            from PIL import Image
        except ImportError as exc:  # Pillow is optional for the client
            raise RuntimeError("decoding png/jpeg frames needs Pillow (pip install 'sdfclient[images]')") from exc
        with Image.open(io.BytesIO(self.data)) as image:
            return np.asarray(image.convert("RGBA"))


@dataclass(frozen=True)
class Pick:
    """The voxel under a pixel, its face normal, and where a placed voxel would go."""

    voxel: Vec3
    normal: Vec3
    place: Vec3
    field_version: int


__all__ = ["Block", "Camera", "ChunkUpdate", "Exported", "Focus", "Frame", "Pick", "QueryResult",
           "StreamMessage", "Vec3", "WorldInfo"]
