"""Renderer: draws frames of a world with ``kernels/render.cl`` and answers picks.

The renderer belongs to the thread that owns the GpuContext (the engine thread
in the server): ``render`` reads the world's field (``world.field_source()``) between steps, so a
frame shows the field of exactly one version, ``frame.field_version``. Output
buffers are allocated through the GpuContext once per frame size and reused;
a few recent sizes are kept (several clients with different windows). Each world's palette
(``config.palette``; None is RGB332) goes to the device once, as 255 RGBA entries, and again
only when the world's palette changes.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import pyopencl as cl
import pyopencl.cltypes as cltypes

from sdfserver.algorithms.base import int4
from sdfserver.gpu import GpuContext
from sdfserver.render.camera import Camera, RenderOptions
from sdfserver.gpu.profiling import event_ms
from sdfserver.world_config import rgb332_palette

FLAG_AO, FLAG_SHADOW, FLAG_STATS = 1, 2, 4
LOCAL_SIZE = (16, 8)
KEEP_SIZES = 4
PALETTE_BYTES = 255 * 4
KEEP_PALETTES = 64  # worlds whose palettes stay on the device (1 KiB each)


@dataclass
class Frame:
    pixels: np.ndarray  # (height, width, 4) uint8 RGBA
    field_version: int
    device_ms: float  # the render kernel's time from its profiling event (0 where there is none)
    wall_ms: float
    reads: np.ndarray | None = None  # (height, width) uint32 field reads per pixel, if asked
    pick: "Pick | None" = None  # the voxel under options.cursor


@dataclass
class Pick:
    voxel: tuple[int, int, int]  # the solid voxel the ray reached
    normal: tuple[int, int, int]  # outward normal of the face it entered; zero if it began inside

    @property
    def place(self) -> tuple[int, int, int]:
        """Where a voxel placed against the hit face goes."""
        return tuple(v + n for v, n in zip(self.voxel, self.normal))


def _float4(v) -> np.ndarray:
    return np.array((*(float(c) for c in v), 0.0), dtype=cltypes.float4)


class _Target:
    """Device buffers for one frame size."""

    def __init__(self, gpu: GpuContext, width: int, height: int):
        self.pixels_bytes = width * height * 4
        self.pixels = gpu.allocate(self.pixels_bytes)
        self.reads = gpu.allocate(self.pixels_bytes)

    def release(self, gpu: GpuContext) -> None:
        gpu.release(self.pixels, self.pixels_bytes)
        gpu.release(self.reads, self.pixels_bytes)


def palette_rgba(palette) -> np.ndarray:
    """A config's palette (None: RGB332) as the kernel's (255, 4) uint8 RGBA table."""
    rgb = rgb332_palette() if palette is None else np.asarray(palette, dtype=np.uint8).reshape(255, 3)
    return np.concatenate([rgb, np.full((255, 1), 255, np.uint8)], axis=1)


class Renderer:
    def __init__(self, gpu: GpuContext):
        self.gpu = gpu
        self._targets: OrderedDict[tuple[int, int], _Target] = OrderedDict()
        self._pick_out = gpu.allocate(32)
        # Per world (by id): the palette object uploaded and its buffer. A config is frozen, so a
        # new palette is a new object; comparing identity costs nothing per frame.
        self._palettes: OrderedDict[int, tuple[object, cl.Buffer]] = OrderedDict()

    def release(self) -> None:
        for target in self._targets.values():
            target.release(self.gpu)
        self._targets.clear()
        for _, buf in self._palettes.values():
            self.gpu.release(buf, PALETTE_BYTES)
        self._palettes.clear()
        if self._pick_out is not None:
            self.gpu.release(self._pick_out, 32)
            self._pick_out = None

    def _target(self, width: int, height: int) -> _Target:
        key = (width, height)
        target = self._targets.pop(key, None)
        if target is None:
            while len(self._targets) >= KEEP_SIZES:
                self._targets.popitem(last=False)[1].release(self.gpu)
            target = _Target(self.gpu, width, height)
        self._targets[key] = target
        return target

    def _palette(self, world) -> cl.Buffer:
        """The device copy of ``world``'s palette, uploaded again when its config's palette changed.
        Worlds that are gone are forgotten as the cache passes KEEP_PALETTES."""
        palette = world.config.palette
        cached = self._palettes.get(id(world))
        if cached is not None and cached[0] is palette:
            self._palettes.move_to_end(id(world))
            return cached[1]
        buf = cached[1] if cached is not None else self.gpu.allocate(PALETTE_BYTES)
        cl.enqueue_copy(self.gpu.queue, buf, palette_rgba(palette))
        self._palettes[id(world)] = (palette, buf)
        self._palettes.move_to_end(id(world))
        # A new world at a released one's address finds its entry and uploads again unless the
        # palette object is the same one (then so are the colours); dropping the least recently
        # drawn entries bounds what released worlds hold.
        while len(self._palettes) > KEEP_PALETTES:
            self.gpu.release(self._palettes.popitem(last=False)[1][1], PALETTE_BYTES)
        return buf

    def render(self, world, camera: Camera, options: RenderOptions = RenderOptions(),
               *, stats: bool = False) -> Frame:
        """One frame of ``world`` (a World) as seen by a validated ``camera``."""
        start = time.perf_counter()
        w, h = camera.width, camera.height
        target = self._target(w, h)
        origin, forward, right, up = camera.basis()
        flags = (FLAG_AO if options.ambient_occlusion else 0) | (FLAG_SHADOW if options.shadows else 0) \
            | (FLAG_STATS if stats else 0)
        light = np.asarray(options.light, dtype=np.float64)
        light /= np.linalg.norm(light)
        pick = None
        centre = options.highlight
        if options.cursor is not None:
            pick = self.pick(world, camera, *options.cursor)
            centre = pick.voxel if pick is not None else None
        if centre is None:
            highlight = int4((0, 0, 0), -1)
        else:
            highlight = int4(centre, int(math.floor(options.highlight_radius ** 2)))
        gsize = tuple(-(-n // l) * l for n, l in zip((w, h), LOCAL_SIZE))
        queue = self.gpu.queue
        defines, field = world.field_source()
        event = self.gpu.programs.kernel("render.cl", "render", **defines)(
            queue, gsize, LOCAL_SIZE,
            *field, int4(world.config.size),
            _float4(origin), _float4(forward), _float4(right), _float4(up),
            np.int32(w), np.int32(h), np.uint32(options.sky_rgb), np.uint32(flags), _float4(light),
            highlight, self._palette(world), target.pixels, target.reads,
        )
        pixels = np.empty((h, w, 4), dtype=np.uint8)
        cl.enqueue_copy(queue, pixels, target.pixels, wait_for=[event])
        reads = None
        if stats:
            reads = np.empty((h, w), dtype=np.uint32)
            cl.enqueue_copy(queue, reads, target.reads, wait_for=[event])
        queue.finish()
        device_ms = event_ms(event) or 0.0  # 0 where the driver gives no time
        return Frame(pixels, world.field_version, device_ms, (time.perf_counter() - start) * 1e3, reads,
                     pick)

    def pick(self, world, camera: Camera, px: float, py: float) -> Pick | None:
        """The voxel under pixel coordinates ``(px, py)`` (a pixel's centre is ``+0.5``), or None."""
        origin, direction = camera.ray(px, py)
        defines, field = world.field_source()
        self.gpu.programs.kernel("render.cl", "pick", **defines)(
            self.gpu.queue, (1,), None, *field, int4(world.config.size),
            _float4(origin), _float4(direction), self._pick_out,
        )
        out = np.empty((2, 4), dtype=np.int32)
        cl.enqueue_copy(self.gpu.queue, out, self._pick_out)
        self.gpu.queue.finish()
        if not out[0, 3]:
            return None
        return Pick(tuple(int(v) for v in out[0, :3]), tuple(int(v) for v in out[1, :3]))
