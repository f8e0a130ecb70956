"""Import and export through a real server: snapshot download / upload, .npy and .vox; imported
worlds get their field computed and survive a restart; bad files are refused."""

import io
import struct

import numpy as np

from durable_server import read_voxels
from references import oracle_distance as oracle

OCTET = {"content-type": "application/octet-stream"}


def field_of(http, world_id, version):
    r = http.get(f"/v1/worlds/{world_id}/field", params={"min_version": version},
                 headers={"accept": "application/octet-stream"})
    assert r.status_code == 200, r.text
    shape = tuple(int(v) for v in r.headers["x-sdf-shape"].split(","))
    return np.frombuffer(r.content, np.uint8).reshape(shape)


def vox_bytes(size, voxels):
    def chunk(cid, content=b"", children=b""):
        return cid + struct.pack("<ii", len(content), len(children)) + content + children
    xyzi = struct.pack("<i", len(voxels)) + b"".join(bytes(v) for v in voxels)
    main = chunk(b"SIZE", struct.pack("<iii", *size)) + chunk(b"XYZI", xyzi)
    return b"VOX " + struct.pack("<i", 150) + chunk(b"MAIN", b"", main)


def test_export_import_round_trips(start_server, tmp_path):
    rng = np.random.default_rng()
    server = start_server()
    http = server.http
    world = http.post("/v1/worlds", json={"size": [16, 8, 24], "chunk_size": 8, "max_distance": 7,
                                          "algorithm": "brute"}).json()["id"]
    rows = np.column_stack([rng.integers(0, 16, 40), rng.integers(0, 8, 40), rng.integers(0, 24, 40),
                            rng.integers(1, 256, 40)])
    http.post(f"/v1/worlds/{world}/edits", json={"edits": [{"op": "voxels", "voxels": rows.tolist()}]})
    version, voxels = read_voxels(http, world)

    snap = http.get(f"/v1/worlds/{world}/export", params={"format": "snapshot"})
    assert snap.status_code == 200 and snap.headers["x-sdf-version"] == str(version)
    npy = http.get(f"/v1/worlds/{world}/export", params={"format": "npy"})
    np.testing.assert_array_equal(np.load(io.BytesIO(npy.content), allow_pickle=False), voxels)
    vox = http.get(f"/v1/worlds/{world}/export", params={"format": "vox"})
    assert vox.content[:4] == b"VOX "

    for fmt, body in (("snapshot", snap.content), ("vox", vox.content)):
        r = http.post("/v1/worlds/import", params={"format": fmt, "chunk_size": 8, "max_distance": 7},
                      content=body, headers=OCTET)
        assert r.status_code == 201, r.text
        copy = r.json()
        assert copy["size"] == [16, 8, 24] and copy["version"] == 1
        if fmt == "snapshot":
            assert copy["algorithm"] == "brute" and copy["max_distance"] == 7
        np.testing.assert_array_equal(read_voxels(http, copy["id"])[1], voxels)
        np.testing.assert_array_equal(field_of(http, copy["id"], 1), oracle(voxels, 7))

    array = rng.integers(0, 256, size=(5, 9, 11)).astype(np.int32)  # (z, y, x), not whole chunks
    stream = io.BytesIO()
    np.save(stream, array)
    r = http.post("/v1/worlds/import", params={"format": "npy", "chunk_size": 8, "max_distance": 4},
                  content=stream.getvalue(), headers=OCTET)
    assert r.status_code == 201, r.text
    imported = r.json()["id"]
    assert r.json()["size"] == [16, 16, 8]
    expected = np.zeros((8, 16, 16), np.uint8)
    expected[:5, :9, :11] = array
    np.testing.assert_array_equal(read_voxels(http, imported)[1], expected)

    model = vox_bytes((3, 2, 4), [(0, 0, 0, 1), (2, 1, 3, 216)])  # default palette: white, red ramp
    r = http.post("/v1/worlds/import", params={"format": "vox", "chunk_size": 8}, content=model, headers=OCTET)
    assert r.status_code == 201, r.text
    got = read_voxels(http, r.json()["id"])[1]
    assert got.shape == (8, 8, 8) and np.count_nonzero(got) == 2
    assert got[2 - 1 - 0, 0, 0] == 1 and got[2 - 1 - 1, 3, 2] == 216  # (x, vz, sy-1-vy), colour indexes
    palette = r.json()["palette"]  # MagicaVoxel's default, as the file has no RGBA chunk
    assert palette[1 - 1] == [255, 255, 255] and palette[216 - 1] == [0xEE, 0, 0]

    for params, body, status in (
            ({"format": "snapshot"}, b"SDFSNAP1garbage", 422), ({"format": "npy"}, b"\x93NUMPY junk", 422),
            ({"format": "vox"}, b"VOX \x96\x00\x00\x00MAIN", 422), ({"format": "tar"}, b"", 422),
            ({"format": "npy", "chunk_size": 7}, stream.getvalue(), 422)):
        r = http.post("/v1/worlds/import", params=params, content=body, headers=OCTET)
        assert r.status_code == status, (params, r.text)
    big = http.post("/v1/worlds", json={"size": [264, 8, 8], "chunk_size": 8}).json()["id"]
    assert http.get(f"/v1/worlds/{big}/export", params={"format": "vox"}).status_code == 413

    server.stop()
    server = start_server(data_dir=tmp_path / "data")
    version, again = read_voxels(server.http, imported)
    assert version == 1
    np.testing.assert_array_equal(again, expected)


def test_worlds_whose_files_pass_max_request_bytes_round_trip_in_every_format(start_server):
    """An import has a limit of its own (max_import_bytes; tests/api/test_imports.py tries it):
    a world whose every file passes max_request_bytes exports and imports back in each format."""
    server = start_server()
    http = server.http
    limit = 1 << 20  # the durability servers' --max-request-bytes
    size = (128, 64, 128)
    assert size[0] * size[1] * size[2] == limit
    voxels = np.random.default_rng().integers(1, 256, size=size[::-1], dtype=np.uint8)  # no air:
    stream = io.BytesIO()  # the largest .vox and an incompressible snapshot
    np.save(stream, voxels)
    assert len(stream.getvalue()) > limit
    r = http.post("/v1/worlds/import", params={"chunk_size": 32}, content=stream.getvalue(), headers=OCTET)
    assert r.status_code == 201, r.text
    world = r.json()["id"]
    for fmt in ("npy", "snapshot", "vox"):
        exported = http.get(f"/v1/worlds/{world}/export", params={"format": fmt})
        assert exported.status_code == 200 and len(exported.content) > limit
        r = http.post("/v1/worlds/import", params={"chunk_size": 32}, content=exported.content, headers=OCTET)
        assert r.status_code == 201, (fmt, r.text)
        assert r.json()["size"] == list(size)
        np.testing.assert_array_equal(read_voxels(http, r.json()["id"])[1], voxels)
        assert http.delete(f"/v1/worlds/{r.json()['id']}").status_code == 204


def test_import_tells_the_format_by_content(start_server):
    http = start_server().http
    array = np.random.default_rng().integers(1, 256, size=(8, 8, 8), dtype=np.uint8)
    stream = io.BytesIO()
    np.save(stream, array)
    npy = stream.getvalue()
    model = vox_bytes((2, 2, 2), [(0, 0, 0, 1)])
    for body in (npy, model):
        r = http.post("/v1/worlds/import", params={"chunk_size": 8}, content=body, headers=OCTET)
        assert r.status_code == 201, r.text
        world = r.json()["id"]
    snapshot = http.get(f"/v1/worlds/{world}/export").content
    r = http.post("/v1/worlds/import", content=snapshot, headers=OCTET)
    assert r.status_code == 201, r.text
    before = http.get("/v1/worlds").json()

    for given, body in (("npy", snapshot), ("snapshot", model), ("vox", npy)):
        r = http.post("/v1/worlds/import", params={"format": given}, content=body, headers=OCTET)
        assert r.status_code == 422, r.text
        assert f"format={given}" in r.json()["error"]["message"]
    for body in (b"PK\x03\x04 a zip file", b"", b"VOX"):
        r = http.post("/v1/worlds/import", content=body, headers=OCTET)
        assert r.status_code == 422, r.text
        message = r.json()["error"]["message"]
        assert all(name in message for name in ("snapshot", "npy", "vox")), message
    assert http.get("/v1/worlds").json() == before
