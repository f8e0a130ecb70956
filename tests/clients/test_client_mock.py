"""sdfclient over httpx.MockTransport: what goes on the wire, and how answers and failures are read."""

from __future__ import annotations

import asyncio
import io

import httpx
import numpy as np
import pytest

import sdfclient
from sdfclient import _wire, edits
from sdfclient.errors import (
    DeviceMemoryExceeded, InternalServerError, InvalidEdit, InvalidInput, NotFound, NotReady, ProtocolError,
    ServerError, Timeout, TooLarge, TransportError, VersionNotReached,
)

MSGPACK = {"content-type": "application/msgpack"}


def msgpack_response(status: int, body) -> httpx.Response:
    return httpx.Response(status, content=_wire.encode(body), headers=MSGPACK)


def error_response(status: int, code: str, message: str = "refused") -> httpx.Response:
    return httpx.Response(status, json={"error": {"code": code, "message": message}})


class Recorder:
    """A handler that records requests and answers from a table of (method, path) -> response."""

    def __init__(self, answers: dict):
        self.answers = answers
        self.requests: list[httpx.Request] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.requests.append(request)
        answer = self.answers[(request.method, request.url.path)]
        return answer(request) if callable(answer) else answer


def test_edit_sends_voxels_as_a_binary_blob():
    rng = np.random.default_rng()
    array = np.concatenate([rng.integers(0, 64, (50, 3)), rng.integers(0, 256, (50, 1))], axis=1)
    handler = Recorder({("POST", "/v1/worlds/w/edits"): msgpack_response(200, {"version": 3})})
    with sdfclient.Client("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
        assert client.edit("w", [array, edits.sphere((1, 2, 3), 4.5, colour=9)]) == 3

    request = handler.requests[0]
    assert request.headers["content-type"] == "application/msgpack"
    raw = _wire.wire.decode(request.content)  # blobs left as maps: what actually travelled
    blob = raw["edits"][0]["voxels"]
    assert blob["dtype"] == "uint16" and blob["shape"] == [50, 4] and isinstance(blob["data"], bytes)
    np.testing.assert_array_equal(np.frombuffer(blob["data"], "<u2").reshape(50, 4), array)
    assert raw["edits"][1] == {"op": "sphere", "center": [1.0, 2.0, 3.0], "radius": 4.5, "colour": 9}


def test_read_field_parameters_and_blob_answer():
    data = np.random.default_rng().integers(0, 1 << 16, (3, 4, 5), dtype=np.uint16)
    handler = Recorder({("GET", "/v1/worlds/w/field"): msgpack_response(
        200, {"origin": [1, 2, 3], "shape": [3, 4, 5], "dtype": "uint16", "version": 7, "data": data})})
    with sdfclient.Client("http://sdf.test/", transport=httpx.MockTransport(handler)) as client:
        block = client.read_field("w", ((1, 2, 3), (6, 6, 6)), format="packed", min_version=7)

    params = handler.requests[0].url.params
    assert dict(params) == {"min": "1,2,3", "max": "6,6,6", "format": "packed", "min_version": "7"}
    assert handler.requests[0].headers["accept"] == "application/msgpack"
    assert block.origin == (1, 2, 3) and block.version == 7
    np.testing.assert_array_equal(block.data, data)
    np.testing.assert_array_equal(block.distance, data >> 8)
    np.testing.assert_array_equal(block.colour, data & 0xFF)


@pytest.mark.parametrize("status, code, cls", [
    (404, "not_found", NotFound),
    (422, "invalid_edit", InvalidEdit),
    (422, "invalid_input", InvalidInput),
    (413, "too_large", TooLarge),
    (507, "device_memory_exceeded", DeviceMemoryExceeded),
    (503, "not_ready", NotReady),
    (503, "version_not_reached", VersionNotReached),
    (500, "kernel_build_error", InternalServerError),
    (418, "teapot", InternalServerError),
])
def test_error_bodies_map_to_the_exception_tree(status, code, cls):
    handler = Recorder({("GET", "/v1/worlds/w"): error_response(status, code, "why it failed")})
    with sdfclient.Client("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
        with pytest.raises(cls) as info:
            client.get_world("w")
    assert type(info.value) is cls
    assert (info.value.status, info.value.code, info.value.message) == (status, code, "why it failed")


def test_errors_without_a_body_map_by_status():
    handler = Recorder({("DELETE", "/v1/worlds/w"): httpx.Response(404, text="nope")})
    with sdfclient.Client("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
        with pytest.raises(NotFound) as info:
            client.delete_world("w")
    assert info.value.status == 404 and info.value.code == "http_404"


def test_unreadable_answers_and_broken_connections():
    def refuse(request):
        raise httpx.ConnectError("connection refused", request=request)

    def slow(request):
        raise httpx.ReadTimeout("too slow", request=request)

    handler = Recorder({
        ("GET", "/v1/worlds"): httpx.Response(200, content=b"\xc1garbage", headers=MSGPACK),
        ("GET", "/v1/worlds/a"): httpx.Response(200, text="<html>", headers={"content-type": "text/html"}),
        ("GET", "/v1/worlds/b"): refuse,
        ("GET", "/v1/worlds/c"): slow,
    })
    with sdfclient.Client("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
        with pytest.raises(ProtocolError):
            client.list_worlds()
        with pytest.raises(ProtocolError):
            client.get_world("a")
        with pytest.raises(TransportError) as info:
            client.get_world("b")
        assert not isinstance(info.value, ServerError)
        with pytest.raises(Timeout):
            client.get_world("c")


def test_bad_arguments_fail_before_sending():
    handler = Recorder({})
    with sdfclient.Client("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
        with pytest.raises(ValueError):
            client.edit("w", [])
        with pytest.raises(ValueError):
            client.edit("w", [np.zeros((3, 3), dtype=np.int64)])
        with pytest.raises(ValueError):
            client.read_field("w", format="rgb")
        with pytest.raises(ValueError):
            client.get_world("../etc")
        with pytest.raises(ValueError):
            client.query("w", [[0.0, float("nan"), 1.0]])
    assert handler.requests == []


def test_async_client_over_mock_transport():
    world = {"id": "w9", "size": [32, 32, 32], "chunk_size": 16, "max_distance": 20, "algorithm": "exact",
             "version": 0, "field_version": 0, "focus": {"center": [1, 1, 1], "size": [2, 2, 2]}}

    def patch(request):
        body = _wire.decode(request.content)
        return msgpack_response(200, {**world, **body})

    handler = Recorder({
        ("POST", "/v1/worlds"): msgpack_response(201, world),
        ("PATCH", "/v1/worlds/w9"): patch,
        ("POST", "/v1/worlds/w9/query"): msgpack_response(
            200, {"distances": np.array([1.0, 2.0], np.float32), "gradients": np.eye(3, dtype=np.float32)[:2],
                  "version": 4}),
    })

    async def run():
        async with sdfclient.AsyncClient("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
            info = await client.create_world((32, 32, 32), max_distance=20,
                                             focus=sdfclient.Focus((1, 1, 1), (2, 2, 2)))
            updated = await client.update_world(info.id, focus=None, algorithm="jfa")
            result = await client.query(info.id, [[1, 2, 3], [4, 5, 6]])
            return info, updated, result

    info, updated, result = asyncio.run(run())
    assert info.focus == sdfclient.Focus((1, 1, 1), (2, 2, 2)) and info.max_distance == 20
    assert updated.focus is None and updated.algorithm == "jfa"
    patched = _wire.decode(handler.requests[1].content)
    assert patched == {"focus": None, "algorithm": "jfa"}
    np.testing.assert_array_equal(result.distances, [1.0, 2.0])
    assert result.gradients.shape == (2, 3) and result.version == 4


def test_api_key_goes_as_a_bearer_token_and_errors_map_by_code():
    import email.utils
    import time

    from sdfclient.errors import RateLimited, Unauthorized, WritesDisabled

    soon = email.utils.formatdate(time.time() + 30, usegmt=True)
    answers = {
        ("GET", "/v1/worlds"): httpx.Response(401, json={"error": {"code": "unauthorized", "message": "no"}},
                                              headers={"www-authenticate": "Bearer"}),
        ("GET", "/v1/worlds/a"): httpx.Response(429, json={"error": {"code": "rate_limited", "message": "slow"}},
                                                headers={"retry-after": "3"}),
        ("GET", "/v1/worlds/b"): httpx.Response(429, text="busy", headers={"retry-after": soon}),
        ("POST", "/v1/worlds/c/edits"): httpx.Response(
            503, json={"error": {"code": "writes_disabled", "message": "log failed"}}, headers={"retry-after": "1"}),
    }
    handler = Recorder(answers)
    with sdfclient.Client("http://sdf.test", api_key="tok-0123456789abcdef", retries=0,
                          transport=httpx.MockTransport(handler)) as client:
        with pytest.raises(Unauthorized) as unauthorized:
            client.list_worlds()
        with pytest.raises(RateLimited) as by_code:
            client.get_world("a")
        with pytest.raises(RateLimited) as by_status:
            client.get_world("b")
        with pytest.raises(WritesDisabled) as writes:
            client.edit("c", [edits.box((0, 0, 0), (1, 1, 1))])
    assert all(r.headers["authorization"] == "Bearer tok-0123456789abcdef" for r in handler.requests)
    assert unauthorized.value.status == 401 and unauthorized.value.retry_after_s is None
    assert by_code.value.retry_after_s == 3.0 and by_code.value.code == "rate_limited"
    assert 25 < by_status.value.retry_after_s <= 30 and by_status.value.code == "http_429"
    assert isinstance(writes.value, NotReady) and writes.value.retry_after_s == 1.0

    handler = Recorder({("GET", "/v1/worlds"): msgpack_response(200, {"worlds": []})})
    with sdfclient.Client("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
        assert client.list_worlds() == []
    assert "authorization" not in handler.requests[0].headers


def test_export_import_and_render_requests(tmp_path):
    voxels = np.random.default_rng().integers(0, 256, (4, 5, 6), dtype=np.uint8)
    npy = io.BytesIO()
    np.save(npy, voxels)
    world = {"id": "n", "size": [6, 5, 4], "chunk_size": 8, "max_distance": 9, "algorithm": "exact", "version": 1}
    pixels = np.random.default_rng().integers(0, 256, (2, 3, 4), dtype=np.uint8)
    handler = Recorder({
        ("GET", "/v1/worlds/w/export"): httpx.Response(200, content=npy.getvalue(), headers={
            "content-type": "application/octet-stream", "x-sdf-version": "7",
            "content-disposition": 'attachment; filename="w.npy"'}),
        ("POST", "/v1/worlds/import"): lambda request: msgpack_response(201, world),
        ("POST", "/v1/worlds/w/render"): httpx.Response(200, content=pixels.tobytes(), headers={
            "content-type": "application/octet-stream", "x-field-version": "5", "x-frame-width": "3",
            "x-frame-height": "2", "x-render-ms": "0.250"}),
    })
    with sdfclient.Client("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
        exported = client.export_world("w", "npy", path=tmp_path / "w.npy")
        (tmp_path / "w.vox").write_bytes(b"VOX fake")
        info = client.import_world(tmp_path / "w.vox", chunk_size=8, model=2)
        client.import_world(voxels, max_distance=9)
        frame = client.render("w", sdfclient.Camera.look_at((1, 2, 3), (0, 0, 0), width=3, height=2),
                              format="rgba", shadows=True, quality=70)
        with pytest.raises(ValueError):
            client.export_world("w", "obj")
        with pytest.raises(ValueError):
            client.import_world(voxels, "vox")
        with pytest.raises(ValueError):
            client.import_world(tmp_path / "w.npy", model=1)  # model is for .vox
    assert exported.version == 7 and exported.filename == "w.npy"
    np.testing.assert_array_equal(exported.array, voxels)
    np.testing.assert_array_equal(np.load(tmp_path / "w.npy"), voxels)
    with pytest.raises(ValueError):
        sdfclient.Exported("vox", 1, b"").array
    assert info.id == "n" and info.size == (6, 5, 4)
    vox_request, npy_request, render_request = handler.requests[1:4]
    assert dict(vox_request.url.params) == {"chunk_size": "8", "model": "2"}  # the server tells the format
    assert vox_request.content == b"VOX fake" and vox_request.headers["content-type"] == "application/octet-stream"
    assert dict(npy_request.url.params) == {"format": "npy", "max_distance": "9"}
    np.testing.assert_array_equal(np.load(io.BytesIO(npy_request.content), allow_pickle=False), voxels)
    body = _wire.decode(render_request.content)
    assert render_request.url.params["format"] == "rgba"
    assert body["position"] == [1.0, 2.0, 3.0] and body["target"] == [0.0, 0.0, 0.0] and "yaw_deg" not in body
    assert body["shadows"] is True and body["quality"] == 70 and body["width"] == 3
    assert (frame.field_version, frame.width, frame.height, frame.render_ms) == (5, 3, 2, 0.25)
    np.testing.assert_array_equal(frame.pixels, pixels)


def test_sphere_and_ray_queries_send_blobs_and_parse_answers():
    answers = {("POST", "/v1/worlds/w/query"): lambda request: msgpack_response(200, (
        {"version": 2, "clearances": np.array([0.5], np.float32), "directions": np.array([[0, 1, 0]], np.float32)}
        if "spheres" in _wire.decode(request.content) else
        {"version": 2, "hits": np.array([1, 0], np.uint8), "distances": np.array([3.0, 9.0], np.float32),
         "normals": np.array([[-1, 0, 0], [0, 0, 0]], np.float32), "colours": np.array([7, 0], np.uint8),
         "voxels": np.array([[4, 1, 1], [-1, -1, -1]], np.int32)}))}
    handler = Recorder(answers)

    async def run_async():
        async with sdfclient.AsyncClient("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
            return await client.query_rays("w", [[0, 1, 1, 1, 0, 0, 9], [0, 1, 1, -1, 0, 0, 9]])

    with sdfclient.Client("http://sdf.test", transport=httpx.MockTransport(handler)) as client:
        spheres = client.query_spheres("w", np.array([[1.0, 2.0, 3.0, 0.5]]), min_version=2)
        for bad in ([[1.0, 2.0, 3.0]], [[1.0, 2.0, 3.0, float("inf")]], np.zeros((0, 4))):
            with pytest.raises(ValueError):
                client.query_spheres("w", bad)
        with pytest.raises(ValueError):
            client.query_rays("w", [[0, 1, 1, 1, 0, 0]])
    rays = asyncio.run(run_async())
    assert spheres.version == 2 and spheres.clearances.tolist() == [0.5] and spheres.directions.shape == (1, 3)
    sent = _wire.decode(handler.requests[0].content)
    assert sent["spheres"].dtype == np.float32 and sent["spheres"].tolist() == [[1.0, 2.0, 3.0, 0.5]]
    assert handler.requests[0].url.params["min_version"] == "2"
    assert rays.hits.dtype == bool and rays.hits.tolist() == [True, False] and rays.voxels.tolist()[1] == [-1, -1, -1]
    assert _wire.decode(handler.requests[1].content)["rays"].shape == (2, 7) and len(handler.requests) == 2
