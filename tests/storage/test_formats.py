"""Import and export: .npy arrays, MagicaVoxel .vox models, and the snapshot format."""

import io
import struct
import zlib

import numpy as np
import pytest

from sdfserver.errors import CorruptData, InvalidInput, TooLarge
from sdfserver.storage import decode_upload, dump_npy, dump_vox, encode_snapshot, load_npy, load_vox
from sdfserver.storage.snapshot import decode_snapshot
from sdfserver.storage.voxfile import default_palette
from sdfserver.world_config import rgb332_palette

CONFIG = {"size": [8, 4, 6], "chunk_size": 8, "max_distance": 9, "algorithm": "exact"}


# -- .npy ----------------------------------------------------------------------------------------

def npy_bytes(array):
    stream = io.BytesIO()
    np.save(stream, array)
    return stream.getvalue()


def test_npy_round_trip_and_conversions():
    rng = np.random.default_rng()
    voxels = rng.integers(0, 256, size=(6, 4, 8), dtype=np.uint8)
    np.testing.assert_array_equal(load_npy(dump_npy(voxels)), voxels)
    np.testing.assert_array_equal(load_npy(npy_bytes(voxels.astype(np.int32))), voxels)
    solid = rng.random((3, 4, 5)) < 0.5
    np.testing.assert_array_equal(load_npy(npy_bytes(solid)), np.where(solid, 255, 0))


@pytest.mark.parametrize("array, match", [
    (np.zeros((4, 4)), "3-D"),
    (np.zeros((2, 2, 2), np.float32), "uint8"),
    (np.full((2, 2, 2), 300, np.int16), "0..255"),
    (np.array([[[None]]], dtype=object), "uint8"),
])
def test_npy_refusals(array, match):
    data = npy_bytes(array) if array.dtype != object else _object_npy(array)
    with pytest.raises(InvalidInput, match=match):
        load_npy(data)


def _object_npy(array):
    stream = io.BytesIO()
    np.save(stream, array, allow_pickle=True)
    return stream.getvalue()


def test_npy_huge_declared_shape_is_refused_before_reading():
    header = {"descr": "|u1", "fortran_order": False, "shape": (4096, 4096, 4096)}
    stream = io.BytesIO()
    np.lib.format.write_array_header_1_0(stream, header)
    with pytest.raises(TooLarge):
        load_npy(b"\x93NUMPY\x01\x00" + stream.getvalue()[8:], max_voxels=1 << 24)
    with pytest.raises(InvalidInput):
        load_npy(b"not numpy at all")


# -- .vox, written byte by byte from the format description ----------------------------------------

def chunk(cid, content=b"", children=b""):
    return cid + struct.pack("<ii", len(content), len(children)) + content + children


def vox_file(size, voxels, palette_rgba=None, extra=b""):
    """'VOX ' 150, MAIN{ PACK, SIZE, XYZI, [unknown chunk], [RGBA] }."""
    children = chunk(b"PACK", struct.pack("<i", 1))
    children += chunk(b"SIZE", struct.pack("<iii", *size))
    children += chunk(b"XYZI", struct.pack("<i", len(voxels)) + b"".join(bytes(v) for v in voxels))
    children += extra
    if palette_rgba is not None:
        children += chunk(b"RGBA", b"".join(bytes(c) for c in palette_rgba))
    return b"VOX " + struct.pack("<i", 150) + chunk(b"MAIN", b"", children)


def test_vox_import_axes_and_palette():
    rng = np.random.default_rng()
    palette = [tuple(int(x) for x in rng.integers(0, 256, size=3)) + (255,) for _ in range(256)]
    palette[6] = (0, 0, 0, 255)  # colour index 7 is black: must stay solid
    size = (5, 3, 4)  # x, y, z with z up
    voxels = [(0, 0, 0, 1), (4, 2, 3, 200), (1, 2, 0, 7), (2, 0, 3, 255)]
    data = vox_file(size, voxels, palette, extra=chunk(b"MATL", b"\x00" * 12))  # skipped
    world, colours = load_vox(data)
    assert world.shape == (3, 4, 5)  # (z, y, x) of a world whose y is the model's z
    expected = np.zeros((3, 4, 5), np.uint8)
    for x, y, z, c in voxels:
        expected[size[1] - 1 - y, z, x] = c  # a voxel's value is its colour index
    np.testing.assert_array_equal(world, expected)
    assert world[size[1] - 1 - 2, 0, 1] == 7
    # The world's palette is the file's: RGBA entry i is colour index i + 1, value i + 1's colour.
    assert colours.shape == (255, 3) and colours.dtype == np.uint8
    np.testing.assert_array_equal(colours, np.array(palette)[:255, :3])


def test_vox_default_palette_matches_the_spec():
    spec = {0: 0x00000000, 1: 0xFFFFFFFF, 2: 0xFFCCFFFF, 7: 0xFFFFCCFF, 36: 0xFF0000FF,
            37: 0xFFFFFFCC, 215: 0xFF330000, 216: 0xFF0000EE, 226: 0xFF00EE00, 236: 0xFFEE0000,
            246: 0xFFEEEEEE, 255: 0xFF111111}
    pal = default_palette()
    assert pal.shape == (256, 3)
    for index, abgr in spec.items():
        assert tuple(pal[index]) == (abgr & 0xFF, (abgr >> 8) & 0xFF, (abgr >> 16) & 0xFF), index
    world, colours = load_vox(vox_file((1, 1, 1), [(0, 0, 0, 216)]))  # no RGBA chunk: default palette
    assert world[0, 0, 0] == 216 and tuple(colours[216 - 1]) == (0xEE, 0, 0)
    np.testing.assert_array_equal(colours, pal[1:])


def test_vox_export_round_trip():
    rng = np.random.default_rng()
    world = rng.integers(0, 256, size=(6, 4, 8), dtype=np.uint8)
    world[rng.random(world.shape) < 0.5] = 0
    voxels, colours = load_vox(dump_vox(world))  # no palette: RGB332's
    np.testing.assert_array_equal(voxels, world)
    np.testing.assert_array_equal(colours, rgb332_palette())
    palette = rng.integers(0, 256, size=(255, 3)).tolist()
    voxels, colours = load_vox(dump_vox(world, palette))
    np.testing.assert_array_equal(voxels, world)
    assert colours.tolist() == palette


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d[:-7], "overruns"),
    (lambda d: b"VOXX" + d[4:], "magic"),
    (lambda d: d.replace(struct.pack("<iii", 2, 2, 2), struct.pack("<iii", 2, 2, 999)), "out of range"),
    (lambda d: d.replace(b"\x01\x01\x01\x05", b"\x01\x09\x01\x05"), "outside"),
])
def test_vox_refusals(mutate, match):
    data = vox_file((2, 2, 2), [(1, 1, 1, 5)])
    with pytest.raises(InvalidInput, match=match):
        load_vox(mutate(data))


# -- snapshots ----------------------------------------------------------------------------------

def test_snapshot_round_trip_and_checks():
    rng = np.random.default_rng()
    voxels = rng.integers(0, 256, size=(6, 4, 8), dtype=np.uint8)
    data = encode_snapshot(12, CONFIG, voxels)
    snap = decode_upload(data)
    assert snap.version == 12 and snap.config == CONFIG
    np.testing.assert_array_equal(snap.voxels, voxels)
    damaged = bytearray(data)
    damaged[-3] ^= 1
    with pytest.raises(CorruptData, match="CRC"):
        decode_snapshot(bytes(damaged), "snap-12")
    with pytest.raises(InvalidInput, match="uploaded snapshot"):
        decode_upload(bytes(damaged))
    with pytest.raises(TooLarge):
        decode_upload(data, max_voxels=100)
    with pytest.raises(InvalidInput):
        decode_upload(b"garbage")


def test_snapshot_that_inflates_beyond_its_declared_size_is_refused():
    import json
    body = zlib.compress(bytes(10 ** 6))  # a small bomb for an 8x4x6 world
    header = json.dumps({"format": 1, "version": 1, "config": CONFIG, "compression": "zlib",
                         "dtype": "uint8", "order": "zyx", "body_bytes": len(body),
                         "body_crc32": zlib.crc32(body)}).encode()
    data = b"SDFSNAP1" + struct.pack("<I", len(header)) + header + body
    with pytest.raises(InvalidInput, match="inflates"):
        decode_upload(data)


# -- .vox scenes: models placed by the scene graph (nTRN, nGRP, nSHP) --------------------------------

def vox_dict(pairs: dict) -> bytes:
    out = struct.pack("<i", len(pairs))
    for k, v in pairs.items():
        out += struct.pack("<i", len(k)) + k.encode() + struct.pack("<i", len(v)) + v.encode()
    return out


def transform(node, child, t=(0, 0, 0), r=None, hidden=False):
    frame = {"_t": " ".join(map(str, t)), **({"_r": str(r)} if r is not None else {})}
    return chunk(b"nTRN", struct.pack("<i", node) + vox_dict({"_hidden": "1"} if hidden else {})
                 + struct.pack("<iiii", child, -1, 0, 1) + vox_dict(frame))


def group(node, children):
    return chunk(b"nGRP", struct.pack("<i", node) + vox_dict({}) + struct.pack("<i", len(children))
                 + b"".join(struct.pack("<i", c) for c in children))


def shape(node, model):
    return chunk(b"nSHP", struct.pack("<i", node) + vox_dict({}) + struct.pack("<ii", 1, model) + vox_dict({}))


def scene_file(models, graph):
    children = chunk(b"PACK", struct.pack("<i", len(models)))
    for size, voxels in models:
        children += chunk(b"SIZE", struct.pack("<iii", *size))
        children += chunk(b"XYZI", struct.pack("<i", len(voxels)) + b"".join(bytes(v) for v in voxels))
    return b"VOX " + struct.pack("<i", 150) + chunk(b"MAIN", b"", children + graph)


MODELS = [((2, 2, 2), [(1, 1, 1, 5)]), ((3, 1, 1), [(0, 0, 0, 7), (2, 0, 0, 9)])]
# a quarter turn about z (row 0 takes column 1, row 1 column 0 negated): bits 1 | 0 << 2 | 1 << 5
QUARTER = 33


def test_a_vox_scene_places_every_model_where_its_graph_says():
    graph = (transform(0, 1) + group(1, [2, 4, 6]) + transform(2, 3) + shape(3, 0)
             + transform(4, 5, t=(10, 0, 0), r=QUARTER) + shape(5, 1)
             + transform(6, 7, t=(40, 40, 40), hidden=True) + shape(7, 0))  # hidden: left out
    world, _ = load_vox(scene_file(MODELS, graph))
    # By hand: model 0's voxel (1,1,1) minus its centre (1,1,1) -> (0,0,0); model 1's (0,0,0) and
    # (2,0,0) minus (1,0,0), turned: (0,1,0) and (0,-1,0), plus (10,0,0). Shifted by the least
    # corner (0,-1,0): (0,1,0), (10,2,0), (10,0,0); z-up (x, y, z) -> world (x, z, 2 - y).
    expected = np.zeros((3, 1, 11), np.uint8)
    expected[1, 0, 0], expected[0, 0, 10], expected[2, 0, 10] = 5, 7, 9  # colour indexes
    np.testing.assert_array_equal(world, expected)
    alone, _ = load_vox(scene_file(MODELS, graph), model=1)  # one model, as it is in its own box
    assert alone.shape == (1, 1, 3) and alone[0, 0, 0] == 7 and alone[0, 0, 2] == 9
    assert load_vox(scene_file(MODELS, b"")).voxels.shape == (2, 2, 2)  # no graph: model 0


@pytest.mark.parametrize("graph, why", [
    (transform(0, 1) + group(1, [1]), "deeper"),  # a group that holds itself
    (transform(0, 1) + shape(1, 5), "model 5"),
    (transform(0, 1, r=0) + shape(1, 0), "rotation"),  # rows 0 and 1 in one column
    (transform(0, 9) + shape(1, 0), "node 9"),
    (chunk(b"nTRN", struct.pack("<i", 0) + vox_dict({}) + struct.pack("<i", 1)) + shape(1, 0), "truncated"),
    (transform(0, 1, t=("x", 0, 0)) + shape(1, 0), "not numbers"),
])
def test_a_broken_vox_scene_is_refused_clearly(graph, why):
    with pytest.raises(InvalidInput) as info:
        load_vox(scene_file(MODELS, graph))
    assert why in str(info.value)


def test_a_vox_scene_larger_than_a_world_is_refused():
    graph = transform(0, 1) + group(1, [2, 4]) + transform(2, 3) + shape(3, 0) + transform(4, 5, t=(5000, 0, 0)) \
        + shape(5, 0)
    with pytest.raises(TooLarge):
        load_vox(scene_file(MODELS, graph))
