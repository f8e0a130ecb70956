"""The perspective camera and the render options, validated on the host.

World coordinates are voxels: voxel ``(x, y, z)`` covers ``[x, x+1) x [y, y+1) x [z, z+1)``,
y is up. ``yaw_deg = 0, pitch_deg = 0`` looks along -z; yaw turns toward +x, pitch toward +y.
Pixel ``(px, py)`` (row 0 at the top) looks through its centre::

    u = (px + 0.5) / width * 2 - 1,   v = 1 - (py + 0.5) / height * 2
    direction = forward + u * right + v * up      (right, up scaled by tan(fov_y / 2))
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Integral
from typing import Any

import numpy as np

from sdfserver import incoming
from sdfserver.errors import InvalidInput, TooLarge

Vec3f = tuple[float, float, float]

MAX_PITCH_DEG = 89.9
# Positions, targets, the light and the cursor: within this many voxels (pixels), so that
# what the kernels compute in float32 stays finite; far beyond any world (2048 a side).
MAX_COORDINATE = 1e6
MAX_INT = (1 << 31) - 1  # integers the kernels take as int32


@dataclass(frozen=True)
class RenderLimits:
    max_width_px: int = 3840
    max_height_px: int = 2160
    max_pixels: int = 3840 * 2160


@dataclass(frozen=True)
class Camera:
    position: Vec3f
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    fov_y_deg: float = 60.0
    width: int = 640
    height: int = 480

    @classmethod
    def look_at(cls, position: Vec3f, target: Vec3f, **kwargs: Any) -> "Camera":
        d = np.asarray(target, dtype=np.float64) - np.asarray(position, dtype=np.float64)
        if not np.all(np.isfinite(d)) or not np.any(d):
            raise InvalidInput(f"look_at needs a target different from the position, got {incoming.short(target)}")
        yaw = math.degrees(math.atan2(d[0], -d[2]))
        pitch = math.degrees(math.atan2(d[1], math.hypot(d[0], d[2])))
        return cls(tuple(float(v) for v in position), yaw, pitch, **kwargs)

    def validated(self, limits: RenderLimits = RenderLimits()) -> "Camera":
        position = _real3(self.position, "position", MAX_COORDINATE)
        yaw, pitch, fov = (_real(v, n) for v, n in ((self.yaw_deg, "yaw_deg"),
                                                    (self.pitch_deg, "pitch_deg"),
                                                    (self.fov_y_deg, "fov_y_deg")))
        if not -90.0 <= pitch <= 90.0:
            raise InvalidInput(f"pitch_deg must be within -90..90, got {pitch:g}")
        if not 1.0 <= fov <= 170.0:
            raise InvalidInput(f"fov_y_deg must be within 1..170, got {fov:g}")
        width, height = (_int(v, n) for v, n in ((self.width, "width"), (self.height, "height")))
        if width < 1 or height < 1:
            raise InvalidInput(f"width and height must be at least 1, got {width}x{height}")
        if width > limits.max_width_px or height > limits.max_height_px \
                or width * height > limits.max_pixels:
            raise TooLarge(f"a {width}x{height} frame is over the limit of "
                           f"{limits.max_width_px}x{limits.max_height_px} "
                           f"({limits.max_pixels} pixels)")
        pitch = max(-MAX_PITCH_DEG, min(MAX_PITCH_DEG, pitch))
        return Camera(position, yaw % 360.0, pitch, fov, width, height)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(origin, forward, right, up) in float64; right and up scaled for the field of view."""
        yaw, pitch = math.radians(self.yaw_deg), math.radians(self.pitch_deg)
        forward = np.array([math.sin(yaw) * math.cos(pitch), math.sin(pitch),
                            -math.cos(yaw) * math.cos(pitch)])
        right = np.array([math.cos(yaw), 0.0, math.sin(yaw)])  # forward x (0, 1, 0), normalized
        up = np.cross(right, forward)
        half = math.tan(math.radians(self.fov_y_deg) / 2)
        aspect = self.width / self.height
        return np.asarray(self.position, dtype=np.float64), forward, right * half * aspect, up * half

    def ray(self, px: float, py: float) -> tuple[np.ndarray, np.ndarray]:
        """Origin and (unnormalized) direction through pixel coordinates (centre: px + 0.5)."""
        origin, forward, right, up = self.basis()
        u = px / self.width * 2 - 1
        v = 1 - py / self.height * 2
        return origin, forward + u * right + v * up


@dataclass(frozen=True)
class RenderOptions:
    ambient_occlusion: bool = False
    shadows: bool = False
    sky_rgb: int = 0x9CC8F0
    light: Vec3f = (0.45, 1.0, 0.3)  # toward the light; normalized by the renderer
    highlight: tuple[int, int, int] | None = None  # brush preview centre (voxel)
    highlight_radius: float = 0.0
    cursor: tuple[float, float] | None = None  # pixel coordinates: pick there, highlight the hit

    def validated(self) -> "RenderOptions":
        for name in ("ambient_occlusion", "shadows"):
            if not isinstance(getattr(self, name), bool):
                raise InvalidInput(f"{name} must be true or false, got {incoming.short(getattr(self, name))}")
        sky = _int(self.sky_rgb, "sky_rgb")
        if not 0 <= sky <= 0xFFFFFF:
            raise InvalidInput(f"sky_rgb must be 0..0xFFFFFF, got {sky}")
        light = _real3(self.light, "light", MAX_COORDINATE)
        if not any(light):
            raise InvalidInput("light must not be the zero vector")
        highlight = None
        if self.highlight is not None:
            highlight = tuple(_int(v, "highlight", MAX_INT) for v in _seq3(self.highlight, "highlight"))
        radius = _real(self.highlight_radius, "highlight_radius")
        if not 0 <= radius <= 256:
            raise InvalidInput(f"highlight_radius must be 0..256, got {radius:g}")
        cursor = None
        if self.cursor is not None:
            if not isinstance(self.cursor, (list, tuple)) or len(self.cursor) != 2:
                raise InvalidInput(f"cursor must be [x, y] pixel coordinates, got {incoming.short(self.cursor)}")
            cursor = tuple(_real(v, "cursor", MAX_COORDINATE) for v in self.cursor)
        return RenderOptions(self.ambient_occlusion, self.shadows, sky, light, highlight, radius, cursor)


def parse_view(raw: Any, limits: RenderLimits = RenderLimits()) -> tuple[Camera, RenderOptions]:
    """A camera and options from their wire form (a JSON object)::

        {"position": [x, y, z], "yaw_deg": 0, "pitch_deg": 0 | "target": [x, y, z],
         "fov_y_deg": 60, "width": 640, "height": 480,
         "ambient_occlusion": false, "shadows": false, "sky_rgb": 10275056,
         "highlight": [x, y, z] | null, "highlight_radius": 0, "cursor": [px, py] | null}

    With a cursor, the voxel under it is picked and highlighted with the brush radius.
    """
    if not isinstance(raw, dict):
        raise InvalidInput(f"a camera must be an object, got {type(raw).__name__}")
    camera_keys = {"position", "yaw_deg", "pitch_deg", "target", "fov_y_deg", "width", "height"}
    option_keys = {f for f in RenderOptions.__dataclass_fields__}
    unknown = set(raw) - camera_keys - option_keys - {"type", "id", "max_fps", "format", "quality"}
    if unknown:
        raise InvalidInput(f"unknown camera fields {sorted(unknown)}")
    if "position" not in raw:
        raise InvalidInput("camera.position is required")
    kwargs = {k: raw[k] for k in ("fov_y_deg", "width", "height") if k in raw}
    if "target" in raw:
        if "yaw_deg" in raw or "pitch_deg" in raw:
            raise InvalidInput("give either target or yaw_deg/pitch_deg, not both")
        camera = Camera.look_at(_real3(raw["position"], "position", MAX_COORDINATE),
                                _real3(raw["target"], "target", MAX_COORDINATE), **kwargs)
    else:
        camera = Camera(raw["position"], raw.get("yaw_deg", 0.0), raw.get("pitch_deg", 0.0), **kwargs)
    options = RenderOptions(**{k: raw[k] for k in option_keys if k in raw})
    return camera.validated(limits), options.validated()


def _seq3(value: Any, name: str) -> tuple:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise InvalidInput(f"{name} must be three numbers [x, y, z], got {incoming.short(value)}")
    return tuple(value)


def _real(value: Any, name: str, bound: float = math.inf) -> float:
    """A finite float within ``bound``; an integer too large for a float is out of range too."""
    number = incoming.finite(value, name)
    if abs(number) > bound:
        raise InvalidInput(f"{name} must be within -{bound:g}..{bound:g}, got {incoming.short(value)}")
    return number


def _real3(value: Any, name: str, bound: float = math.inf) -> Vec3f:
    return tuple(_real(v, name, bound) for v in _seq3(value, name))


def _int(value: Any, name: str, bound: int = MAX_INT) -> int:
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise InvalidInput(f"{name} must be an integer, got {incoming.short(value)}")
    if not -bound - 1 <= value <= bound:
        raise InvalidInput(f"{name} must be within {-bound - 1}..{bound}, got {incoming.short(value)}")
    return int(value)
