"""MagicaVoxel ``.vox`` models (the RIFF-like format of ephtracy/voxel-model's
``MagicaVoxel-file-format-vox.txt``).

Layout: ``"VOX "``, int32 version, then the ``MAIN`` chunk whose children are an optional
``PACK`` (model count), one ``SIZE`` (x, y, z; z is up) and ``XYZI`` (count, then x, y, z,
colour index as bytes) per model, and an optional ``RGBA`` palette (256 RGBA entries; entry
``i`` is colour index ``i + 1``). Every chunk is id, int32 content bytes, int32 children
bytes. The scene graph (``nTRN``, ``nGRP``, ``nSHP``) places the models in one scene
(``voxscene.py``); other chunks (materials, layers) are skipped.

Import: z-up becomes y-up keeping the handedness — world (x, y, z) = (vx, vz, sy - 1 - vy) —
and colours are kept as the file has them: a voxel's value is its MagicaVoxel colour index
(1..255; 0 is air on both sides) and the world's palette is the file's (its ``RGBA`` chunk, else
MagicaVoxel's default), so nothing is quantised. A whole scene is imported as one world: its
placed voxels' bounding box, at most ``MAX_SCENE_SIDE`` a side. Export writes one model whose
colour index is the voxel's value and whose ``RGBA`` chunk is the world's palette (RGB332 where
the world has none), for worlds up to 256 voxels a side.
"""

from __future__ import annotations

import struct

import numpy as np

from typing import NamedTuple

from sdfserver.errors import InvalidInput, TooLarge
from sdfserver.storage.voxscene import SceneGraph, place

VOX_MAGIC = b"VOX "
MAX_SCENE_SIDE = 2048  # a dense world's largest side
_CHUNK = struct.Struct("<4sii")
MAX_SIDE = 256


def default_palette() -> np.ndarray:
    """MagicaVoxel's default palette as (256, 3) uint8 RGB, indexed by colour index."""
    levels = np.array([0xFF, 0xCC, 0x99, 0x66, 0x33, 0x00], dtype=np.uint8)
    r, g, b = np.meshgrid(levels, levels, levels, indexing="ij")  # blue varies fastest
    cube = np.stack([r.ravel(), g.ravel(), b.ravel()], axis=1)[:-1]  # 215 colours, no black
    ramp = np.array([0xEE, 0xDD, 0xBB, 0xAA, 0x88, 0x77, 0x55, 0x44, 0x22, 0x11], dtype=np.uint8)
    zeros = np.zeros_like(ramp)
    ramps = [np.stack(c, axis=1) for c in ((ramp, zeros, zeros), (zeros, ramp, zeros),
                                           (zeros, zeros, ramp), (ramp, ramp, ramp))]
    return np.concatenate([np.zeros((1, 3), np.uint8), cube, *ramps])


def rgb332_to_rgb(colour: np.ndarray) -> np.ndarray:
    """Each RGB332 level spread over 0..255 (the inverse of ``rgb_to_rgb332`` up to rounding)."""
    c = colour.astype(np.uint16)
    rgb = np.stack([(c >> 5) * 255 // 7, ((c >> 2) & 7) * 255 // 7, (c & 3) * 255 // 3], axis=-1)
    return rgb.astype(np.uint8)


def _chunks(data: bytes, start: int, end: int):
    """Yield (id, content, children range) for the chunks in data[start:end]."""
    offset = start
    while offset < end:
        if end - offset < _CHUNK.size:
            raise InvalidInput(f".vox: truncated chunk header at offset {offset}")
        cid, n, m = _CHUNK.unpack_from(data, offset)
        body = offset + _CHUNK.size
        if n < 0 or m < 0 or body + n + m > end:
            raise InvalidInput(f".vox: chunk {cid!r} at offset {offset} overruns its parent")
        yield cid, data[body:body + n], (body + n, body + n + m)
        offset = body + n + m


Model = tuple[tuple[int, int, int], np.ndarray]  # (size xyz, xyzi (N, 4) uint8)


def parse_vox(data: bytes, *, max_voxels: int | None = None) -> tuple[list[Model], np.ndarray, SceneGraph]:
    """([(size xyz, xyzi (N, 4) uint8)] per model, palette (256, 3) RGB by colour index, the
    scene graph: empty when the file has none)."""
    if len(data) < 8 or data[:4] != VOX_MAGIC:
        raise InvalidInput(".vox: missing 'VOX ' magic")
    chunks = list(_chunks(data, 8, len(data)))
    if not chunks or chunks[0][0] != b"MAIN":
        raise InvalidInput(".vox: the first chunk must be MAIN")
    models, size, palette, scene = [], None, default_palette(), SceneGraph()
    for cid, content, (lo, hi) in _chunks(data, *chunks[0][2]):
        if cid in (b"nTRN", b"nGRP", b"nSHP"):
            scene.add(cid, content)
        elif cid == b"SIZE":
            if len(content) < 12:
                raise InvalidInput(".vox: SIZE chunk shorter than 12 bytes")
            size = struct.unpack_from("<3i", content)
            if min(size) <= 0 or max(size) > MAX_SIDE:
                raise InvalidInput(f".vox: model size {list(size)} out of range 1..{MAX_SIDE}")
            if max_voxels is not None and size[0] * size[1] * size[2] > max_voxels:
                raise TooLarge(f".vox: a {list(size)} model exceeds the limit of {max_voxels} voxels")
        elif cid == b"XYZI":
            if size is None:
                raise InvalidInput(".vox: XYZI chunk before its SIZE chunk")
            (count,) = struct.unpack_from("<i", content) if len(content) >= 4 else (-1,)
            if count < 0 or 4 + 4 * count > len(content):
                raise InvalidInput(f".vox: XYZI declares {count} voxels in {len(content)} bytes")
            xyzi = np.frombuffer(content, dtype=np.uint8, count=4 * count, offset=4).reshape(-1, 4)
            if (xyzi[:, :3] >= np.array(size)).any():
                raise InvalidInput(f".vox: a voxel lies outside its model size {list(size)}")
            models.append((tuple(size), xyzi))
            size = None
        elif cid == b"RGBA":
            if len(content) < 1024:
                raise InvalidInput(".vox: RGBA chunk shorter than 1024 bytes")
            rgba = np.frombuffer(content, dtype=np.uint8, count=1024).reshape(256, 4)
            palette = np.concatenate([np.zeros((1, 3), np.uint8), rgba[:255, :3]])
    if not models:
        raise InvalidInput(".vox: no model (SIZE + XYZI) found")
    return models, palette, scene


class VoxWorld(NamedTuple):
    voxels: np.ndarray  # uint8 (z, y, x), each voxel its colour index
    palette: np.ndarray  # (255, 3) uint8 RGB, row v - 1 the colour of value v (WorldConfig.palette)


def load_vox(data: bytes, *, model: int | None = None, max_voxels: int | None = None) -> VoxWorld:
    """World voxels and the file's palette: model ``model`` alone, or (None) the file's whole
    scene (model 0 of a file without a scene graph)."""
    models, palette, scene = parse_vox(data, max_voxels=max_voxels)
    placements = scene.placements(len(models)) if model is None else []
    if model is None and not placements:
        model = 0
    if model is not None:
        if not 0 <= model < len(models):
            raise InvalidInput(f".vox: model {model} requested, the file has {len(models)}")
        (sx, sy, sz), xyzi = models[model]
        solid = xyzi[xyzi[:, 3] != 0].astype(np.int64)
        coords, indexes, extent = solid[:, :3], solid[:, 3], np.array([sx, sy, sz])
    else:
        coords, indexes = place(models, placements)
        coords = coords - coords.min(axis=0)
        extent = coords.max(axis=0) + 1
        if extent.max() > MAX_SCENE_SIDE or (max_voxels is not None and int(np.prod(extent)) > max_voxels):
            raise TooLarge(f".vox: the scene spans {extent.tolist()} voxels; a world holds at most "
                           f"{MAX_SCENE_SIDE} a side and {max_voxels} voxels (import one model with model=)")
    sx, sy, sz = (int(v) for v in extent)
    voxels = np.zeros((sy, sz, sx), dtype=np.uint8)  # world (z, y, x) from vox (x, y, z up)
    voxels[sy - 1 - coords[:, 1], coords[:, 2], coords[:, 0]] = indexes
    return VoxWorld(voxels, np.ascontiguousarray(palette[1:256]))


def dump_vox(voxels: np.ndarray, palette=None) -> bytes:
    """World voxels (z, y, x) as a one-model .vox file; ``palette``: the world's (255 RGB
    colours, row v - 1 for value v), None for RGB332."""
    nz, ny, nx = voxels.shape
    if max(voxels.shape) > MAX_SIDE:
        raise TooLarge(f".vox export holds at most {MAX_SIDE} voxels a side, got {list(voxels.shape[::-1])}")
    z, y, x = np.nonzero(voxels)
    xyzi = np.stack([x, nz - 1 - z, y, voxels[z, y, x]], axis=1).astype(np.uint8)

    def chunk(cid: bytes, content: bytes, children: bytes = b"") -> bytes:
        return _CHUNK.pack(cid, len(content), len(children)) + content + children

    rgba = np.zeros((256, 4), dtype=np.uint8)
    rgba[:255, :3] = rgb332_to_rgb(np.arange(1, 256)) if palette is None \
        else np.asarray(palette, dtype=np.uint8).reshape(255, 3)
    rgba[:255, 3] = 255
    children = (chunk(b"SIZE", struct.pack("<3i", nx, nz, ny))
                + chunk(b"XYZI", struct.pack("<i", len(xyzi)) + xyzi.tobytes())
                + chunk(b"RGBA", rgba.tobytes()))
    return VOX_MAGIC + struct.pack("<i", 150) + chunk(b"MAIN", b"", children)
