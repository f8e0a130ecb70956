"""A sparse world exported as its bricks (a snapshot, format 2) and imported back through a real
server: the copy equals the original on every stored and implicit brick and the oracle's field;
hostile files are refused with a 4xx and create nothing."""

from __future__ import annotations

import json
import struct
import zlib

import httpx
import numpy as np
import pytest
from references import oracle_distance
from server_process import ServerProcess


from .conftest import random_batch, read

SIZE, BRICK, CAP = [256, 64, 192], 16, 6
FLAGS = ["--memory-budget-bytes", str(256 << 20), "--max-read-voxels", str(1 << 22), "--workers", "1"]
OCTET = {"content-type": "application/octet-stream"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    process = ServerProcess(tmp_path_factory.mktemp("sparse-transfer") / "data", *FLAGS).wait_ready()
    yield process
    process.stop()


def whole(http: httpx.Client, world_id: str, what: str) -> np.ndarray:
    return read(http, world_id, what, (0, 0, 0), SIZE)


def edited_world(http: httpx.Client, rng: np.random.Generator, batches: int = 6) -> str:
    r = http.post("/v1/worlds", json={"size": SIZE, "chunk_size": BRICK, "max_distance": CAP, "storage": "sparse"})
    assert r.status_code == 201, r.text
    world = r.json()["id"]
    for _ in range(batches):
        r = http.post(f"/v1/worlds/{world}/edits", json={"edits": random_batch(rng, SIZE, BRICK)})
        assert r.status_code == 200, r.text
    return world


def test_a_sparse_world_exports_its_bricks_and_imports_back_equal(server, rng):
    with httpx.Client(base_url=server.url, timeout=120) as http:
        world = edited_world(http, rng)
        described = http.get(f"/v1/worlds/{world}").json()
        r = http.get(f"/v1/worlds/{world}/export")
        assert r.status_code == 200, r.text
        exported = r.content
        assert exported[:8] == b"SDFSNAP1"
        stored = described["stored_bricks"] * BRICK ** 3
        assert len(exported) < stored  # the bricks, compressed: not the 3 MB of a dense copy
        r = http.post("/v1/worlds/import", content=exported, headers=OCTET)
        assert r.status_code == 201, r.text
        copy = r.json()
        assert copy["storage"] == "sparse" and copy["size"] == SIZE and copy["stored_bricks"] == described["stored_bricks"]
        voxels = whole(http, world, "voxels")
        np.testing.assert_array_equal(whole(http, copy["id"], "voxels"), voxels)
        field = whole(http, copy["id"], "field")
        np.testing.assert_array_equal(field, whole(http, world, "field"))
        np.testing.assert_array_equal(field >> 8, oracle_distance(voxels.astype(np.uint8), CAP))
        # the copy takes edits like any sparse world
        r = http.post(f"/v1/worlds/{copy['id']}/edits", json={"edits": [{"op": "box", "min": [0, 0, 0],
                                                                          "max": [20, 20, 20], "colour": 9}]})
        assert r.status_code == 200, r.text
        voxels = whole(http, copy["id"], "voxels")
        np.testing.assert_array_equal(whole(http, copy["id"], "field") >> 8, oracle_distance(voxels, CAP))


def rebuilt(data: bytes, *, header_edit=None, raw_edit=None) -> bytes:
    """The snapshot with its header or inflated body changed, framing made consistent again."""
    (header_len,) = struct.unpack_from("<I", data, 8)
    header = json.loads(data[12:12 + header_len])
    raw = zlib.decompress(data[12 + header_len:])
    if raw_edit is not None:
        raw = raw_edit(bytearray(raw), header)
    if header_edit is not None:
        header_edit(header)
    body = zlib.compress(bytes(raw))
    header.update(body_bytes=len(body), body_crc32=zlib.crc32(body))
    encoded = json.dumps(header).encode()
    return data[:8] + struct.pack("<I", len(encoded)) + encoded + body


def test_hostile_sparse_files_are_refused_and_create_nothing(server, rng):
    with httpx.Client(base_url=server.url, timeout=120) as http:
        world = edited_world(http, rng, batches=3)
        exported = http.get(f"/v1/worlds/{world}/export").content
        before = {w["id"] for w in http.get("/v1/worlds").json()["worlds"]}
        (header_len,) = struct.unpack_from("<I", exported, 8)
        header = json.loads(exported[12:12 + header_len])
        field_at = header["blocks_bytes"] + header["bricks"] * BRICK ** 3

        def flip_distance(raw, header):  # one stored voxel's distance changed, its voxels kept
            at = field_at + 2 * (BRICK ** 3 // 2) + 1
            raw[at] = (raw[at] + 1) % CAP
            return raw

        def block_outside(raw, header):
            raw[0:4] = struct.pack("<i", 1000)
            return raw

        def colours_lie(raw, header):
            raw[field_at] ^= 0x5A
            return raw

        hostile = {
            "truncated": exported[:-100],
            "bad magic": b"XDFSNAP1" + exported[8:],
            "crc": exported[:-1] + bytes([exported[-1] ^ 1]),
            "bomb": rebuilt(exported, header_edit=lambda h: h.update(bricks=1 << 24)),
            "wrong field": rebuilt(exported, raw_edit=flip_distance),
            "colours that are not the voxels": rebuilt(exported, raw_edit=colours_lie),
            "block outside": rebuilt(exported, raw_edit=block_outside),
            "brick not the chunk": rebuilt(exported, header_edit=lambda h: h["config"].update(chunk_size=32)),
        }
        for name, data in hostile.items():
            r = http.post("/v1/worlds/import", content=data, headers=OCTET)
            assert 400 <= r.status_code < 500, (name, r.status_code, r.text)
            assert r.json()["error"]["message"], name
        assert {w["id"] for w in http.get("/v1/worlds").json()["worlds"]} == before
