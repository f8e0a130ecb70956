"""Hostile msgpack and WebSocket frames: nesting bombs, huge declared lengths, truncation,
NaN/inf and wrong types get a clear 4xx (or an error frame) while the server's memory stays
bounded and the world — voxels, version and log — is left exactly as it was."""

from __future__ import annotations

import json

import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from sdfserver import wire

from durable_server import read_voxels
from server_process import tree_rss_bytes

MP = {"content-type": "application/msgpack", "accept": "application/msgpack"}
BOX = {"op": "box", "min": [0, 0, 0], "max": [16, 16, 16], "colour": 9}  # would change everything


def edits(*ops) -> bytes:
    return wire.encode({"edits": [BOX, *ops]})


HOSTILE = {
    "nesting bomb": b"\x81\xa5edits" + b"\x91" * 60_000 + b"\xc0",
    "nesting bomb in a map": b"\x81" * 50_000 + b"\xc0",
    "array declares 4G items": b"\x81\xa5edits\xdd\xff\xff\xff\xff" + b"\xc0" * 8,
    "map declares 4G pairs": b"\xdf\xff\xff\xff\xff" + b"\xc0" * 8,
    "bin declares 4 GiB": b"\x81\xa5edits\x91\x82\xa2op\xa6voxels\xa6voxels\xc6\xff\xff\xff\xff" + b"\x00" * 64,
    "str declares 4 GiB": b"\x81\xdb\xff\xff\xff\xff" + b"e" * 64,
    "ext declares 4 GiB": b"\x81\xa5edits\xc9\xff\xff\xff\xff\x01" + b"\x00" * 64,
    "truncated in a blob": edits({"op": "voxels", "voxels": np.ones((50, 4), np.uint16)})[:-37],
    "blob shape lies": edits({"op": "voxels", "voxels": {"dtype": "uint16", "shape": [1 << 30, 4],
                                                         "data": b"\x00" * 8}}),
    "blob negative shape": edits({"op": "voxels", "voxels": {"dtype": "uint16", "shape": [-1, 4],
                                                             "data": b"\x00" * 8}}),
    "-inf centre": edits({"op": "sphere", "center": [1, float("-inf"), 1], "radius": 2, "colour": 1}),
    "NaN radius": edits({"op": "sphere", "center": [1, 1, 1], "radius": float("nan"), "colour": 1}),
    "float where an int goes": edits({"op": "box", "min": [0.5, 0, 0], "max": [1, 1, 1], "colour": 1}),
    "huge integer": edits({"op": "box", "min": [0, 0, 0], "max": [1, 1, 1], "colour": 2 ** 64 - 1}),
    "ops not maps": edits(7, "box", None),
    "edits a map": wire.encode({"edits": {"op": "box"}}),
    "voxels a string": edits({"op": "voxels", "voxels": "1,2,3,4"}),
    "voxel rows ragged": edits({"op": "voxels", "voxels": [[1, 2, 3, 4], [1, 2]]}),
    "bytes as keys": b"\x81\xc4\x05edits\x90",
}


@pytest.fixture
def target(start_server, tmp_path):
    server = start_server("--max-request-bytes", str(1 << 16))
    r = server.http.post("/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8})
    world = r.json()["id"]
    server.http.post(f"/v1/worlds/{world}/edits", json={"edits": [{"op": "box", "min": [2, 2, 2],
                                                                    "max": [5, 6, 7], "colour": 77}]})
    return server, world, tmp_path / "data" / "worlds" / world


def snapshot_state(server, world, directory):
    version, voxels = read_voxels(server.http, world)
    log = b"".join(p.read_bytes() for p in sorted(directory.glob("wal-*")))
    return version, voxels.tobytes(), log


def test_hostile_http_bodies(target):
    server, world, directory = target
    before = snapshot_state(server, world, directory)
    rss = tree_rss_bytes(server.process.pid)
    for name, body in HOSTILE.items():
        r = server.http.post(f"/v1/worlds/{world}/edits", content=body, headers=MP)
        assert r.status_code in (413, 422), (name, r.status_code, r.text)
        message = r.json()["error"]["message"]
        assert message and len(message) < 2000, name
    r = server.http.post(f"/v1/worlds/{world}/edits", content=b"[" * 60_000,
                         headers={"content-type": "application/json"})
    assert r.status_code == 422 and "JSON" in r.json()["error"]["message"]
    r = server.http.post(f"/v1/worlds/{world}/edits", content=json.dumps({"edits": [BOX]}).encode() * 3000,
                         headers={"content-type": "application/json"})
    assert r.status_code == 413
    assert snapshot_state(server, world, directory) == before
    assert tree_rss_bytes(server.process.pid) - rss < 64 << 20, "memory grew by more than 64 MiB"


def test_hostile_websocket_frames(target):
    server, world, directory = target
    before = snapshot_state(server, world, directory)
    url = server.url.replace("http://", "ws://") + f"/v1/worlds/{world}/stream"
    with connect(url, max_size=None) as ws:
        for name, body in HOSTILE.items():
            typed = b"\x82\xa4type\xa5edits\xa5edits"  # {type: "edits", edits: ...}
            frame = body if name == "nesting bomb" else body.replace(b"\x81\xa5edits", typed, 1)
            ws.send(frame)
            answer = wire.decode(ws.recv(timeout=10))
            assert answer["type"] == "error" and answer["error"]["code"] in (
                "invalid_input", "invalid_edit", "too_large"), (name, answer)
        ws.send(wire.encode({"type": "ping", "id": 3}))
        assert wire.decode(ws.recv(timeout=10)) == {"type": "pong", "id": 3}
        ws.send(b"\x00" * ((1 << 16) + 1))  # over max_request_bytes: the server closes with 1009
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009
    assert snapshot_state(server, world, directory) == before
