"""Imports of real-sized worlds through a real server: a limit of their own (max_import_bytes, not
max_request_bytes), the body spooled to disk and gone afterwards, ``storage=sparse`` on npy and
vox imports (the solid voxels as edit batches, the field exact), the sparse export's version
header, and a warning where a sparse world costs more device memory than a dense one would."""

from __future__ import annotations

import io
import math
import struct

import httpx
import numpy as np
import pytest
from references import oracle_distance
from server_process import ServerProcess

from sdfserver.api.transfer import solid_voxel_batches

IMPORT_LIMIT = 300_000
PER_BATCH = 700  # --max-voxels-per-batch: a sparse import of more solids takes several batches
FLAGS = ["--max-request-bytes", str(1 << 16), "--max-import-bytes", str(IMPORT_LIMIT),
         "--max-voxels-per-batch", str(PER_BATCH), "--memory-budget-bytes", str(256 << 20), "--workers", "1"]
OCTET = {"content-type": "application/octet-stream"}


@pytest.fixture
def rng() -> np.random.Generator:
    seed = int(np.random.SeedSequence().entropy % (1 << 32))
    print(f"seed {seed}")  # shown with a failure
    return np.random.default_rng(seed)


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("imports") / "data"
    process = ServerProcess(data, *FLAGS).wait_ready()
    process.data_dir = data
    yield process
    process.stop()


@pytest.fixture
def http(server):
    with httpx.Client(base_url=server.url, timeout=120) as client:
        yield client


def npy(array: np.ndarray) -> bytes:
    stream = io.BytesIO()
    np.save(stream, array)
    return stream.getvalue()


def scene(rng: np.random.Generator, shape: tuple[int, int, int]) -> np.ndarray:
    """A floor and random blobs of random colours, air elsewhere: (z, y, x) uint8."""
    voxels = np.zeros(shape, np.uint8)
    voxels[:, :2, :] = rng.integers(1, 256)
    z, y, x = np.indices(shape)
    for _ in range(4):
        c = [int(rng.integers(0, n)) for n in shape]
        r = int(rng.integers(2, 6))
        voxels[(z - c[0]) ** 2 + (y - c[1]) ** 2 + (x - c[2]) ** 2 <= r * r] = rng.integers(1, 256)
    return voxels


def world_ids(http: httpx.Client) -> set[str]:
    return {w["id"] for w in http.get("/v1/worlds").json()["worlds"]}


def voxels_of(http: httpx.Client, world_id: str) -> np.ndarray:
    r = http.get(f"/v1/worlds/{world_id}/export", params={"format": "npy"})
    assert r.status_code == 200, r.text
    return np.load(io.BytesIO(r.content), allow_pickle=False)


def field_of(http: httpx.Client, world_id: str, version: int) -> np.ndarray:
    r = http.get(f"/v1/worlds/{world_id}/field", params={"min_version": version},
                 headers={"accept": "application/octet-stream"})
    assert r.status_code == 200, r.text
    return np.frombuffer(r.content, np.uint8).reshape([int(v) for v in r.headers["x-sdf-shape"].split(",")])


def test_an_import_past_max_request_bytes_is_taken_and_one_past_max_import_bytes_is_not(server, http, rng):
    array = rng.integers(1, 256, size=(30, 64, 64), dtype=np.uint8)  # 120 kB: past max_request_bytes
    r = http.post("/v1/worlds/import", params={"chunk_size": 16}, content=npy(array), headers=OCTET)
    assert r.status_code == 201, r.text
    assert http.delete(f"/v1/worlds/{r.json()['id']}").status_code == 204

    before = world_ids(http)
    over = npy(np.ones((1, 1, IMPORT_LIMIT), np.uint8))
    r = http.post("/v1/worlds/import", content=over, headers=OCTET)  # declared: refused unread
    assert r.status_code == 413 and r.json()["error"]["code"] == "too_large", r.text
    assert "max_import_bytes" in r.json()["error"]["message"]

    def undeclared():  # no Content-Length: refused as it passes the limit
        for at in range(0, len(over), 1 << 14):
            yield over[at:at + (1 << 14)]

    with httpx.Client(base_url=server.url, timeout=120) as fresh:
        r = fresh.post("/v1/worlds/import", content=undeclared(), headers=OCTET)
    assert r.status_code == 413, r.text
    assert world_ids(http) == before
    assert list((server.data_dir / "imports").iterdir()) == []  # the spooled bodies went with their imports


def test_a_sparse_world_from_an_npy_array_has_its_voxels_and_an_exact_field(http, rng):
    array = scene(rng, (40, 24, 56))
    solids = int(np.count_nonzero(array))
    assert solids > 2 * PER_BATCH
    r = http.post("/v1/worlds/import", params={"chunk_size": 16, "max_distance": 6, "storage": "sparse"},
                  content=npy(array), headers=OCTET)
    assert r.status_code == 201, r.text
    world = r.json()
    assert world["storage"] == "sparse" and world["size"] == [64, 32, 48]
    assert world["version"] == math.ceil(solids / PER_BATCH)  # one edit batch per PER_BATCH solids
    grown = np.zeros((48, 32, 64), np.uint8)
    grown[:40, :24, :56] = array
    np.testing.assert_array_equal(voxels_of(http, world["id"]), grown)
    np.testing.assert_array_equal(field_of(http, world["id"], world["version"]), oracle_distance(grown, 6))

    r = http.get(f"/v1/worlds/{world['id']}/export")  # its bricks, with the version they hold
    assert r.status_code == 200 and r.content[:8] == b"SDFSNAP1"
    assert int(r.headers["x-sdf-version"]) == world["version"]
    r = http.post("/v1/worlds/import", content=r.content, headers=OCTET)
    assert r.status_code == 201 and r.json()["storage"] == "sparse", r.text
    np.testing.assert_array_equal(voxels_of(http, r.json()["id"]), grown)
    for w in (world["id"], r.json()["id"]):
        assert http.delete(f"/v1/worlds/{w}").status_code == 204


def test_a_sparse_world_from_a_vox_file_keeps_its_colours(http):
    def chunk(cid, content=b"", children=b""):
        return cid + struct.pack("<ii", len(content), len(children)) + content + children

    solid = [(x, y, z, 1 + (x + y + z) % 7) for x in range(4) for y in range(3) for z in range(5)]
    xyzi = struct.pack("<i", len(solid)) + b"".join(bytes(v) for v in solid)
    model = b"VOX " + struct.pack("<i", 150) + chunk(
        b"MAIN", b"", chunk(b"SIZE", struct.pack("<iii", 4, 3, 5)) + chunk(b"XYZI", xyzi))
    r = http.post("/v1/worlds/import", params={"chunk_size": 8, "storage": "sparse", "max_distance": 4},
                  content=model, headers=OCTET)
    assert r.status_code == 201, r.text
    world = r.json()
    assert world["storage"] == "sparse" and world["palette"] is not None and world["version"] == 1
    voxels = voxels_of(http, world["id"])
    assert np.count_nonzero(voxels) == len(solid) and set(np.unique(voxels)) == set(range(8))
    assert http.delete(f"/v1/worlds/{world['id']}").status_code == 204


def test_a_sparse_world_that_costs_more_than_a_dense_one_says_so(http, rng):
    array = rng.integers(0, 2, size=(32, 32, 32), dtype=np.uint8)  # surfaces everywhere: every brick stored
    r = http.post("/v1/worlds/import", params={"chunk_size": 16, "storage": "sparse"}, content=npy(array),
                  headers=OCTET)
    assert r.status_code == 201, r.text
    world = r.json()
    dense = 5 * 32 ** 3 + 32 * 64  # what World.buffer_bytes gives a dense 32^3 world (work's pad per plane)
    assert world["device_bytes"] > dense
    (warning,) = world["warnings"]
    assert "more than" in warning and "storage=dense" in warning
    assert "warnings" not in http.get(f"/v1/worlds/{world['id']}").json()

    r = http.post("/v1/worlds/import", params={"chunk_size": 16}, content=npy(array), headers=OCTET)
    assert r.status_code == 201 and "warnings" not in r.json(), r.text  # a dense world: nothing to say
    for w in (world["id"], r.json()["id"]):
        assert http.delete(f"/v1/worlds/{w}").status_code == 204


def test_storage_is_refused_with_a_snapshot_and_bad_values(http, rng):
    array = scene(rng, (16, 16, 16))
    r = http.post("/v1/worlds/import", params={"chunk_size": 16}, content=npy(array), headers=OCTET)
    world = r.json()["id"]
    snapshot = http.get(f"/v1/worlds/{world}/export").content
    before = world_ids(http)
    for params, body in (({"storage": "sparse"}, snapshot), ({"storage": "bricks"}, npy(array)),
                         ({"storage": "sparse", "algorithm": "jfa"}, npy(array))):
        r = http.post("/v1/worlds/import", params=params, content=body, headers=OCTET)
        assert r.status_code == 422, (params, r.text)
    assert world_ids(http) == before
    assert http.delete(f"/v1/worlds/{world}").status_code == 204


@pytest.mark.parametrize("per_batch", [1, 5, 64, 10_000])
def test_solid_voxels_come_in_batches_of_at_most_the_limit_in_array_order(rng, per_batch, monkeypatch):
    monkeypatch.setattr("sdfserver.api.transfer.SOLID_SCAN_VOXELS", 97)  # stretches that split batches
    voxels = (rng.random((7, 9, 11)) < 0.2).astype(np.uint8) * rng.integers(1, 256, (7, 9, 11), dtype=np.uint8)
    batches = list(solid_voxel_batches(voxels, per_batch))
    assert all(0 < len(b) <= per_batch for b in batches) and all(len(b) == per_batch for b in batches[:-1])
    rows = np.concatenate(batches) if batches else np.zeros((0, 4), np.uint16)
    assert rows.dtype == np.uint16
    z, y, x = np.nonzero(voxels)
    np.testing.assert_array_equal(rows, np.column_stack([x, y, z, voxels[z, y, x]]))
    assert list(solid_voxel_batches(np.zeros((3, 3, 3), np.uint8), per_batch)) == []
