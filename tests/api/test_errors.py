"""Every bad-input class gets its 4xx with the one error body, and the world is left unchanged."""

from __future__ import annotations

import json

import msgpack
import numpy as np
import pytest
import websockets.sync.client
from websockets.exceptions import ConnectionClosed

from sdfserver import wire

MP = {"content-type": wire.CONTENT_TYPE}
JS = {"content-type": "application/json"}


def assert_error(response, status: int, code: str | None = None) -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith("application/json")
    body = response.json()
    assert set(body) == {"error"}
    error = body["error"]
    assert set(error) <= {"code", "message", "detail"} and {"code", "message"} <= set(error)
    assert isinstance(error["code"], str) and isinstance(error["message"], str) and error["message"]
    if code is not None:
        assert error["code"] == code, error
    return error


@pytest.fixture(scope="module")
def world(server):
    wid = server.create_world(size=[32, 32, 32], chunk_size=8, max_distance=8)["id"]
    rng = np.random.default_rng()
    rows = np.column_stack([rng.integers(0, 32, (50, 3)), rng.integers(1, 256, 50)]).astype(np.uint16)
    server.edit(wid, [{"op": "voxels", "voxels": rows}, {"op": "sphere", "center": [16, 16, 16],
                                                          "radius": 5.5, "colour": 3}])
    yield wid
    server.http.delete(f"/v1/worlds/{wid}")


def nan_sphere():
    return {"edits": [{"op": "sphere", "center": [1.0, float("nan"), 2.0], "radius": 2.0, "colour": 1}]}


def good_op():
    return {"op": "box", "min": [0, 0, 0], "max": [32, 32, 32], "colour": 200}


# (name, body bytes, headers, status, code). Each begins with an op that would change
# everything, where there is room for one, to show that the batch applies whole or not at all.
EDIT_CASES = [
    ("malformed msgpack", b"\xc1\xff\x00", MP, 422, "invalid_input"),
    ("truncated msgpack", wire.encode({"edits": [good_op()]})[:-3], MP, 422, "invalid_input"),
    ("trailing msgpack", wire.encode({"edits": [good_op()]}) + b"\x00", MP, 422, "invalid_input"),
    ("msgpack ext type", msgpack.packb({"edits": msgpack.ExtType(5, b"xx")}), MP, 422, "invalid_input"),
    ("malformed json", b'{"edits": [', JS, 422, "invalid_input"),
    ("unsupported content type", b"edits=1", {"content-type": "text/plain"}, 422, "invalid_input"),
    ("edits not a list", wire.encode({"edits": "box"}), MP, 422, "invalid_edit"),
    ("extra field", wire.encode({"edits": [good_op()], "x": 1}), MP, 422, "invalid_edit"),
    ("empty batch", wire.encode({"edits": []}), MP, 422, "invalid_edit"),
    ("unknown op", wire.encode({"edits": [good_op(), {"op": "cone"}]}), MP, 422, "invalid_edit"),
    ("missing field", wire.encode({"edits": [good_op(), {"op": "box", "min": [0, 0, 0]}]}), MP, 422,
     "invalid_edit"),
    ("colour as string", json.dumps({"edits": [good_op(), {"op": "box", "min": [0, 0, 0], "max": [1, 1, 1],
                                                           "colour": "red"}]}).encode(), JS, 422, "invalid_edit"),
    ("bool coordinate", wire.encode({"edits": [good_op(), {"op": "box", "min": [True, 0, 0], "max": [1, 1, 1],
                                                           "colour": 1}]}), MP, 422, "invalid_edit"),
    ("float voxel blob", wire.encode({"edits": [good_op(), {"op": "voxels",
                                                            "voxels": np.zeros((2, 4), np.float32)}]}), MP, 422,
     "invalid_edit"),
    ("blob with wrong byte count", wire.encode({"edits": [good_op(), {"op": "voxels", "voxels": {
        "dtype": "uint16", "shape": [3, 4], "data": b"\x00" * 10}}]}), MP, 422, "invalid_input"),
    ("blob with bad dtype", wire.encode({"edits": [good_op(), {"op": "voxels", "voxels": {
        "dtype": "object", "shape": [1, 4], "data": b"\x00" * 8}}]}), MP, 422, "invalid_input"),
    ("NaN in json", b'{"edits": [{"op": "sphere", "center": [1, NaN, 2], "radius": 2, "colour": 1}]}', JS, 422,
     "invalid_input"),
    ("NaN in msgpack", wire.encode({"edits": [good_op(), *nan_sphere()["edits"]]}), MP, 422, "invalid_edit"),
    ("infinite radius", wire.encode({"edits": [good_op(), {"op": "sphere", "center": [1, 1, 1],
                                                           "radius": float("inf"), "colour": 1}]}), MP, 422,
     "invalid_edit"),
    ("voxel outside the world", wire.encode({"edits": [good_op(), {"op": "voxels", "voxels": np.array(
        [[1, 1, 1, 5], [32, 0, 0, 5]], np.uint16)}]}), MP, 422, "invalid_edit"),
    ("negative voxel", json.dumps({"edits": [good_op(), {"op": "voxels", "voxels": [[1, -1, 1, 5]]}]}).encode(),
     JS, 422, "invalid_edit"),
    ("colour 256", wire.encode({"edits": [good_op(), {"op": "box", "min": [0, 0, 0], "max": [1, 1, 1],
                                                      "colour": 256}]}), MP, 422, "invalid_edit"),
    ("voxel colour 300", wire.encode({"edits": [good_op(), {"op": "voxels", "voxels": np.array(
        [[1, 1, 1, 300]], np.uint16)}]}), MP, 422, "invalid_edit"),
    ("radius over the limit", wire.encode({"edits": [good_op(), {"op": "sphere", "center": [1, 1, 1],
                                                                 "radius": 41, "colour": 1}]}), MP, 422,
     "invalid_edit"),
    ("inverted box", wire.encode({"edits": [good_op(), {"op": "box", "min": [5, 0, 0], "max": [1, 1, 1],
                                                        "colour": 1}]}), MP, 422, "invalid_edit"),
    ("too many operations", wire.encode({"edits": [good_op()] * 65}), MP, 413, "too_large"),
    ("too many voxels", wire.encode({"edits": [good_op(), {"op": "voxels", "voxels": np.ones((20001, 4),
                                                                                             np.uint16)}]}),
     MP, 413, "too_large"),
    ("body over the limit", wire.encode({"edits": [good_op(), {"op": "voxels", "voxels": np.ones(
        (140_000, 4), np.uint16)}]}), MP, 413, "too_large"),
]


@pytest.mark.parametrize("name,body,headers,status,code", EDIT_CASES, ids=[c[0] for c in EDIT_CASES])
def test_bad_edits_change_nothing(server, world, name, body, headers, status, code):
    before = server.state(world)
    r = server.http.post(f"/v1/worlds/{world}/edits", content=body, headers=headers)
    assert_error(r, status, code)
    assert server.state(world) == before


def test_oversized_body_without_content_length(server, world):
    before = server.state(world)
    body = wire.encode({"edits": [{"op": "voxels", "voxels": np.ones((140_000, 4), np.uint16)}]})
    r = server.http.post(f"/v1/worlds/{world}/edits", content=iter([body[:1000], body[1000:]]), headers=MP)
    assert_error(r, 413, "too_large")
    assert server.state(world) == before


BAD_READS = [
    ("field", {"min_version": "abc"}, 422, "invalid_input"),
    ("field", {"format": "rgb"}, 422, "invalid_input"),
    ("field", {"min": "0,0", "max": "1,1,1"}, 422, "invalid_input"),
    ("field", {"min": "0,0,0"}, 422, "invalid_input"),
    ("field", {"min": "0,0,0", "max": "33,1,1"}, 422, "invalid_input"),
    ("voxels", {"min": "4,4,4", "max": "2,8,8"}, 422, "invalid_input"),
    ("voxels", {"min": "-1,0,0", "max": "1,1,1"}, 422, "invalid_input"),
    ("field", {"min_version": "-1"}, 422, "invalid_input"),
]


@pytest.mark.parametrize("what,params,status,code", BAD_READS)
def test_bad_reads(server, world, what, params, status, code):
    assert_error(server.http.get(f"/v1/worlds/{world}/{what}", params=params), status, code)


def test_read_box_over_the_limit(server):
    wid = server.create_world(size=[64, 64, 80], chunk_size=16, max_distance=4)["id"]
    assert_error(server.http.get(f"/v1/worlds/{wid}/field"), 413, "too_large")
    assert server.http.get(f"/v1/worlds/{wid}/field", params={"min": "0,0,0", "max": "64,64,64"}).status_code == 200
    server.http.delete(f"/v1/worlds/{wid}")


def test_min_version_not_reached(server, world):
    version = server.state(world)[0]
    r = server.http.get(f"/v1/worlds/{world}/field", params={"min_version": version + 1})
    assert_error(r, 503, "version_not_reached")
    assert r.headers["retry-after"] == "1"


@pytest.mark.parametrize("body,status,code", [
    ({"points": [[1, 2]]}, 422, "invalid_input"),
    ({"points": [[1, 2, "x"]]}, 422, "invalid_input"),
    ({"points": [[1, 2, 40]]}, 422, "invalid_input"),
    ({"points": [[-0.5, 2, 3]]}, 422, "invalid_input"),
    ({"points": []}, 422, "invalid_input"),
    ({"pts": [[1, 2, 3]]}, 422, "invalid_input"),
    ({"points": [[1.0, 2.0, 3.0]] * 1001}, 413, "too_large"),
])
def test_bad_queries(server, world, body, status, code):
    assert_error(server.http.post(f"/v1/worlds/{world}/query", json=body), status, code)


def test_nan_query_in_json_and_msgpack(server, world):
    r = server.http.post(f"/v1/worlds/{world}/query", content=b'{"points": [[1, NaN, 2]]}', headers=JS)
    assert_error(r, 422, "invalid_input")
    r = server.post(f"/v1/worlds/{world}/query", {"points": np.array([[1, np.nan, 2]], np.float32)})
    assert_error(r, 422, "invalid_input")
    r = server.post(f"/v1/worlds/{world}/query", {"points": np.array([[1, 2, 3, 4]], np.float32)})
    assert_error(r, 422, "invalid_input")


@pytest.mark.parametrize("body,status,code", [
    ({"size": [32, 32]}, 422, "invalid_input"),
    ({"size": [32, 32, "32"]}, 422, "invalid_input"),
    ({"size": [30, 32, 32], "chunk_size": 16}, 422, "invalid_input"),
    ({"size": [32, 32, 32], "chunk_size": 12}, 422, "invalid_input"),
    ({"size": [32, 32, 32], "max_distance": 256}, 422, "invalid_input"),
    ({"size": [32, 32, 32], "algorithm": "magic"}, 422, "invalid_input"),
    ({"size": [32, 32, 32], "colour": 1}, 422, "invalid_input"),
    ({"size": [32, 32, 32], "focus": {"center": [0, 0, 0], "size": [0, 1, 1]}}, 422, "invalid_input"),
    ({"size": [512, 256, 256]}, 413, "too_large"),
    ({"size": [256, 256, 128]}, 507, "device_memory_exceeded"),
])
def test_bad_worlds_are_not_created(server, body, status, code):
    before = server.http.get("/v1/worlds").json()["worlds"]
    assert_error(server.http.post("/v1/worlds", json=body), status, code)
    assert server.http.get("/v1/worlds").json()["worlds"] == before


@pytest.mark.parametrize("body", [{"algorithm": "magic"}, {"max_distance": 0}, {"size": [8, 8, 8]},
                                  {"focus": {"center": [0, 0], "size": [1, 1, 1]}}])
def test_bad_patch_changes_nothing(server, world, body):
    before = server.http.get(f"/v1/worlds/{world}").json()
    assert_error(server.http.patch(f"/v1/worlds/{world}", json=body), 422, "invalid_input")
    assert server.http.get(f"/v1/worlds/{world}").json() == before


def test_work_over_the_recompute_limit_is_refused_at_the_door(server):
    before = server.http.get("/v1/worlds").json()["worlds"]
    r = server.http.post("/v1/worlds", json={"size": [128, 128, 128], "algorithm": "brute"})
    assert_error(r, 422, "recompute_cost_exceeded")
    assert "brute at 128³, cap 255 would scan 4.4e12 voxel pairs" in r.json()["error"]["message"]
    assert "this server allows 3e10" in r.json()["error"]["message"]
    assert server.http.get("/v1/worlds").json()["worlds"] == before
    world = server.create_world(size=[128, 128, 128])["id"]
    try:
        described = server.http.get(f"/v1/worlds/{world}").json()
        assert_error(server.http.patch(f"/v1/worlds/{world}", json={"algorithm": "brute"}), 422,
                     "recompute_cost_exceeded")
        assert server.http.get(f"/v1/worlds/{world}").json() == described
    finally:
        server.http.delete(f"/v1/worlds/{world}")


@pytest.mark.parametrize("method,path", [
    ("GET", "/v1/worlds/nope"), ("DELETE", "/v1/worlds/nope"), ("GET", "/v1/worlds/nope/field"),
    ("GET", "/v1/worlds/nope/voxels"), ("PATCH", "/v1/worlds/nope"), ("POST", "/v1/worlds/nope/edits"),
    ("POST", "/v1/worlds/nope/query"), ("GET", "/v1/nothing-here"),
])
def test_unknown_world(server, method, path):
    body = {"edits": [good_op()]} if path.endswith("edits") else {"points": [[1, 1, 1]]} \
        if path.endswith("query") else {"algorithm": "exact"}
    r = server.http.request(method, path, json=body if method in ("POST", "PATCH") else None)
    assert_error(r, 404, "not_found")


def test_wrong_method_has_the_error_shape(server, world):
    assert_error(server.http.put(f"/v1/worlds/{world}/edits", json={}), 405, "method_not_allowed")


def test_websocket_unknown_world_closes_4404(server):
    with websockets.sync.client.connect(server.ws_url + "/v1/worlds/nope/stream") as ws:
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd.code == 4404


def test_websocket_bad_frames_answer_errors_and_change_nothing(server, world):
    before = server.state(world)
    with websockets.sync.client.connect(server.ws_url + f"/v1/worlds/{world}/stream") as ws:
        for frame in (b"\xc1", wire.encode([1, 2]), wire.encode({"type": "fly"}),
                      wire.encode({"type": "edits", "id": 7, "edits": [good_op(), *nan_sphere()["edits"]]}),
                      wire.encode({"type": "subscribe", "id": 8, "min": [0, 0, 0], "max": [64, 8, 8]})):
            ws.send(frame)
            answer = wire.decode(ws.recv(timeout=10))
            assert answer["type"] == "error" and set(answer["error"]) >= {"code", "message"}
        assert answer["id"] == 8
        ws.send("text frame")
        assert wire.decode(ws.recv(timeout=10))["error"]["code"] == "invalid_input"
        ws.send(wire.encode({"type": "ping", "id": 1}))
        assert wire.decode(ws.recv(timeout=10)) == {"type": "pong", "id": 1}
    assert server.state(world) == before
