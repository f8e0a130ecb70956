"""Sparse worlds through the API of a real server: creation and its limits, edits, field, voxel
and point reads, the stream of changed chunks, a generated terrain rendered, and a restart that
rebuilds a sparse world from its log."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
import websockets.sync.client
from references import apply_edits, oracle_distance
from server_process import ServerProcess

from .conftest import read

from sdfserver import wire

FLAGS = ["--memory-budget-bytes", str(256 << 20), "--max-read-voxels", str(1 << 20), "--workers", "1",
         "--snapshot-every-batches", "2", "--snapshot-min-interval-s", "0"]
SIZE, BRICK, CAP = [65536, 256, 65536], 32, 7


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("sparse-api") / "data"


@pytest.fixture(scope="module")
def server(data_dir):
    process = ServerProcess(data_dir, *FLAGS).wait_ready()
    yield process
    process.stop()


def test_creation_and_its_limits(server):
    with httpx.Client(base_url=server.url, timeout=60) as http:
        r = http.post("/v1/worlds", json={"size": SIZE, "chunk_size": BRICK, "max_distance": CAP})
        assert r.status_code == 422 and "sparse" in r.text  # a dense world stops at 2048 a side
        r = http.post("/v1/worlds", json={"size": [65536, 8192, 64], "chunk_size": BRICK, "storage": "sparse"})
        assert r.status_code == 422
        r = http.post("/v1/worlds", json={"size": [64, 64, 64], "generate": {"kind": "terrain"}})
        assert r.status_code == 422  # generate is for sparse worlds
        r = http.post("/v1/worlds", json={"size": [4096, 1024, 4096], "chunk_size": BRICK, "storage": "sparse",
                                          "generate": {"kind": "terrain", "seed": 1}})
        assert r.status_code == 507  # its surface band cannot fit a 256 MiB budget; nothing kept
        r = http.post("/v1/worlds", json={"size": SIZE, "chunk_size": BRICK, "max_distance": CAP, "storage": "sparse"})
        assert r.status_code == 201, r.text
        described = http.get(f"/v1/worlds/{r.json()['id']}").json()
        assert described["storage"] == "sparse" and described["stored_bricks"] == 0
        assert described["device_bytes"] == 0 and described["bytes_per_stored_voxel"] is None


def test_edits_reads_queries_and_the_stream(server):
    rng = np.random.default_rng()
    with httpx.Client(base_url=server.url, timeout=60) as http:
        wid = http.post("/v1/worlds", json={"size": SIZE, "chunk_size": BRICK, "max_distance": CAP,
                                            "storage": "sparse"}).json()["id"]
        lo, hi = [40000, 64, 49984], [40064, 128, 50048]  # one neighbourhood of the huge world
        with websockets.sync.client.connect(server.url.replace("http", "ws") + f"/v1/worlds/{wid}/stream") as ws:
            ws.send(wire.encode({"type": "subscribe", "id": "s", "min": lo, "max": hi, "format": "packed"}))
            assert wire.decode(ws.recv(timeout=30))["type"] == "subscribed"
            assert wire.decode(ws.recv(timeout=30))["version"] == 0
            local = np.full((64, 64, 64), CAP << 8, dtype=np.uint16)
            expected = np.zeros((64, 64, 64), dtype=np.uint8)
            for i in range(3):
                centre = [int(rng.integers(l + 8, h - 8)) for l, h in zip(lo, hi)]
                # radius 3 or more: the sphere reaches past the box that cuts it (from centre - 2),
                # so some of its voxels stay and the world keeps bricks
                batch = [{"op": "sphere", "center": centre, "radius": float(rng.uniform(3, 7)), "colour": 30 + i},
                         {"op": "box", "min": [c - 2 for c in centre], "max": [c + 5 for c in centre], "colour": 0}]
                r = http.post(f"/v1/worlds/{wid}/edits", json={"edits": batch})
                assert r.status_code == 200, r.text
                version = r.json()["version"]
                apply_edits(expected, [{**op, **({"center": [c - l for c, l in zip(op["center"], lo)]}
                                                  if op["op"] == "sphere" else
                                                  {"min": [c - l for c, l in zip(op["min"], lo)],
                                                   "max": [c - l for c, l in zip(op["max"], lo)]})}
                                       for op in batch])
                while True:  # chunks until this version's arrive
                    frame = wire.decode(ws.recv(timeout=30))
                    for chunk in frame["chunks"]:
                        data = wire.unpack_array(chunk["data"])
                        x, y, z = (o - l for o, l in zip(chunk["origin"], lo))
                        local[z:z + data.shape[0], y:y + data.shape[1], x:x + data.shape[2]] = data
                    if frame["version"] >= version:
                        break
        field = read(http, wid, "field", lo, hi)
        voxels = read(http, wid, "voxels", lo, hi)
        assert np.array_equal(voxels, expected)
        assert np.array_equal(field >> 8, oracle_distance(expected, CAP))  # nothing else within the cap
        assert np.array_equal(local, field)
        points = [[lo[0] + 32.5, lo[1] + 32.5, lo[2] + 32.5], [5.0, 5.0, 5.0], [65535.0, 255.0, 65535.0]]
        r = http.post(f"/v1/worlds/{wid}/query", json={"points": points})
        assert r.status_code == 200, r.text
        assert r.json()["distances"][1:] == [CAP, CAP]
        assert r.json()["distances"][0] == int(field[32, 32, 32] >> 8)
        described = http.get(f"/v1/worlds/{wid}").json()
        assert 0 < described["stored_bricks"] <= 64 and described["device_bytes"] < 96 << 20


def test_a_generated_terrain_renders_and_a_restart_rebuilds_it(server, data_dir):
    with httpx.Client(base_url=server.url, timeout=120) as http:
        r = http.post("/v1/worlds", json={"size": [512, 128, 512], "chunk_size": BRICK, "max_distance": 15,
                                          "storage": "sparse", "generate": {"kind": "terrain", "seed": 5}})
        assert r.status_code == 201, r.text
        wid = r.json()["id"]
        assert http.get(f"/v1/worlds/{wid}").json()["stored_bricks"] > 0
        r = http.post(f"/v1/worlds/{wid}/edits", json={"edits": [{"op": "sphere", "center": [256, 60, 256],
                                                                    "radius": 9, "colour": 0}]})
        assert r.status_code == 200
        for centre in ([100, 60, 100], [400, 60, 400]):  # two more batches: a snapshot, then one after it
            r = http.post(f"/v1/worlds/{wid}/edits", json={"edits": [{"op": "sphere", "center": centre,
                                                                        "radius": 6, "colour": 0xE0}]})
            assert r.status_code == 200
        box = ([224, 32, 224], [288, 96, 288])
        before = read(http, wid, "field", *box)
        view = {"position": [-50, 180, -50], "target": [256, 40, 256], "width": 160, "height": 120,
                "format": "png"}
        r = http.post(f"/v1/worlds/{wid}/render", json=view)
        assert r.status_code == 200, r.text
        assert r.content[:4] == b"\x89PNG"
        near = ([64, 32, 64], [128, 96, 128])
        before_near = read(http, wid, "field", *near)
    server.stop()
    snapshots = [p for p in data_dir.rglob("*.sdfsnap") if wid in str(p)]
    assert snapshots and b'"format": 2' in snapshots[0].read_bytes()[:4096]  # a sparse world's own format
    restarted = ServerProcess(data_dir, *FLAGS).wait_ready()
    try:
        with httpx.Client(base_url=restarted.url, timeout=120) as http:
            assert np.array_equal(read(http, wid, "field", *box), before)
            assert np.array_equal(read(http, wid, "field", *near), before_near)
            assert http.get(f"/v1/worlds/{wid}").json()["version"] == 3
    finally:
        restarted.stop()
