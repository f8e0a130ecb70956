"""sdfclient over httpx.MockTransport: what goes on the wire, and how answers and failures are read."""

from __future__ import annotations

import asyncio

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
