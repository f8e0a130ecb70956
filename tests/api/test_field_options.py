"""A world's field options through a real server: every metric and sign, dense and sparse, read
as distances and packed in msgpack, JSON and raw bytes and checked against SciPy after random
edits; PATCH of the metric and sign (a new field) and of voxel_size, origin and palette (the same
field); every bad value refused with a 422 naming the field, changing nothing; the stream of a
Euclidean world. A restart keeping the options is tests/durability/test_field_options_restart.py."""

from __future__ import annotations

import base64

import numpy as np
import pytest
import websockets.sync.client
from references import field_distances

from sdfserver import wire

SIZE = (24, 16, 16)  # x, y, z: three chunks of 8 along x, two along y and z
CAP = 5  # small, so that the cap is reached inside the world
OPTIONS = [("manhattan", False), ("manhattan", True), ("euclidean", False), ("euclidean", True)]
DISTANCE_DTYPES = {("manhattan", False): "uint8", ("manhattan", True): "int16",
                   ("euclidean", False): "float32", ("euclidean", True): "float32"}
PACKED_CONTENT = {"manhattan": "distance_colour", "euclidean": "squared_distance"}


def expected_packed(voxels: np.ndarray, d: np.ndarray, metric: str) -> np.ndarray:
    magnitude = np.abs(d)
    if metric == "euclidean":
        return np.rint(magnitude ** 2).astype(np.uint16)
    return (magnitude.astype(np.uint16) << 8) | voxels.astype(np.uint16)


def read_three_ways(server, world_id: str, fmt: str, version: int, **box) -> tuple[np.ndarray, str, str]:
    """The field read as msgpack, JSON and raw bytes, which must agree: (array, dtype, content)."""
    path, params = f"/v1/worlds/{world_id}/field", {"format": fmt, "min_version": version, **box}
    r = server.http.get(path, params=params, headers={"accept": wire.CONTENT_TYPE})
    assert r.status_code == 200, r.text
    msg = wire.decode(r.content)
    dtype, content, shape = msg["dtype"], msg["content"], tuple(msg["shape"])
    array = np.frombuffer(msg["data"], np.dtype(dtype).newbyteorder("<")).reshape(shape)

    r = server.http.get(path, params=params, headers={"accept": "application/json"})
    assert r.status_code == 200, r.text
    js = r.json()
    assert (js["dtype"], js["content"], tuple(js["shape"]), js["encoding"]) == (dtype, content, shape, "base64")
    np.testing.assert_array_equal(
        np.frombuffer(base64.b64decode(js["data"]), np.dtype(dtype).newbyteorder("<")).reshape(shape), array)

    r = server.http.get(path, params=params, headers={"accept": "application/octet-stream"})
    assert r.status_code == 200, r.text
    assert (r.headers["x-sdf-dtype"], r.headers["x-sdf-content"]) == (dtype, content)
    assert tuple(map(int, r.headers["x-sdf-shape"].split(","))) == shape
    np.testing.assert_array_equal(np.frombuffer(r.content, np.dtype(dtype).newbyteorder("<")).reshape(shape), array)
    return array, dtype, content


def check_field(server, world_id: str, voxels: np.ndarray, version: int, metric: str, signed: bool) -> None:
    """Both formats of the whole world, and a box across chunk borders, against SciPy."""
    d = field_distances(voxels, metric, signed, CAP)
    distances, dtype, content = read_three_ways(server, world_id, "distance", version)
    assert (dtype, content) == (DISTANCE_DTYPES[metric, signed], "distance")
    if metric == "euclidean":
        np.testing.assert_allclose(distances, d, rtol=0, atol=1e-5)
    else:
        np.testing.assert_array_equal(distances, d.astype(dtype))
    if signed:
        assert (distances < 0).sum() == (voxels != 0).sum()  # never 0: the sign follows the voxel
        assert not (distances == 0).any()
    packed, dtype, content = read_three_ways(server, world_id, "packed", version)
    assert (dtype, content) == ("uint16", PACKED_CONTENT[metric])
    np.testing.assert_array_equal(packed, expected_packed(voxels, d, metric))
    box, _, _ = read_three_ways(server, world_id, "distance", version, min="5,3,7", max="19,12,10")
    np.testing.assert_array_equal(box, distances[7:10, 3:12, 5:19])


def edit(server, world_id: str, voxels: np.ndarray, batch: list[dict], ref) -> int:
    version = server.edit(world_id, batch)
    ref.apply(voxels, batch)
    return version


@pytest.mark.parametrize("storage", ["dense", "sparse"])
@pytest.mark.parametrize("metric,signed", OPTIONS)
def test_fields_of_every_metric_and_sign_match_scipy(server, ref, storage, metric, signed):
    rng = np.random.default_rng()
    described = server.create_world(size=list(SIZE), chunk_size=8, max_distance=CAP, storage=storage,
                                    metric=metric, signed=signed)
    wid = described["id"]
    assert (described["metric"], described["signed"], described["storage"]) == (metric, signed, storage)
    voxels = np.zeros(SIZE[::-1], np.uint8)
    # A batch clipped to nothing (wholly past a face) still counts as a version and changes nothing.
    assert edit(server, wid, voxels, [{"op": "box", "min": [30, 0, 0], "max": [34, 2, 2], "colour": 1}], ref) == 1
    # A solid across a chunk border and through a world face, then random batches.
    version = edit(server, wid, voxels, [{"op": "box", "min": [6, -2, 5], "max": [11, 4, 12], "colour": 7}], ref)
    check_field(server, wid, voxels, version, metric, signed)
    for _ in range(3):
        version = edit(server, wid, voxels, ref.batch(rng, SIZE), ref)
    server_voxels, _ = server.read(wid, "voxels", min_version=version)
    np.testing.assert_array_equal(server_voxels, voxels)
    check_field(server, wid, voxels, version, metric, signed)
    server.http.delete(f"/v1/worlds/{wid}")


@pytest.mark.parametrize("storage", ["dense", "sparse"])
def test_patch_of_metric_and_sign_recomputes_the_field(server, ref, storage):
    rng = np.random.default_rng()
    wid = server.create_world(size=list(SIZE), chunk_size=8, max_distance=CAP, storage=storage)["id"]
    voxels = np.zeros(SIZE[::-1], np.uint8)
    version = edit(server, wid, voxels, [{"op": "box", "min": [0, 0, 0], "max": [24, 2, 16], "colour": 3},
                                         *ref.batch(rng, SIZE)], ref)
    check_field(server, wid, voxels, version, "manhattan", False)
    for metric, signed in [("euclidean", False), ("euclidean", True), ("manhattan", True), ("manhattan", False)]:
        r = server.http.patch(f"/v1/worlds/{wid}", json={"metric": metric, "signed": signed})
        assert r.status_code == 200, r.text
        assert (r.json()["metric"], r.json()["signed"], r.json()["version"]) == (metric, signed, version)
        check_field(server, wid, voxels, version, metric, signed)
        version = edit(server, wid, voxels, ref.batch(rng, SIZE), ref)  # and incremental updates go on
        check_field(server, wid, voxels, version, metric, signed)
    server.http.delete(f"/v1/worlds/{wid}")


@pytest.mark.parametrize("storage", ["dense", "sparse"])
def test_patch_of_placement_and_palette_keeps_the_field(server, storage):
    wid = server.create_world(size=list(SIZE), chunk_size=8, max_distance=CAP, storage=storage,
                              metric="euclidean", signed=True)["id"]
    version = server.edit(wid, [{"op": "sphere", "center": [12, 8, 8], "radius": 4.5, "colour": 9}])
    before, _ = server.read(wid, "field", min_version=version)
    described = server.http.get(f"/v1/worlds/{wid}").json()
    palette = np.random.default_rng().integers(0, 256, (255, 3)).tolist()
    for change in ({"voxel_size": 0.25}, {"origin": [-3.0, 0.5, 1e6]}, {"palette": palette},
                   {"voxel_size": 2, "origin": [1, 2, 3], "palette": None}):
        r = server.http.patch(f"/v1/worlds/{wid}", json=change)
        assert r.status_code == 200, r.text
        after = r.json()
        assert (after["version"], after["field_version"]) == (described["version"], described["field_version"])
        for key, value in change.items():
            if value is not None:
                assert after[key] == (palette if key == "palette" else value), key
        field, _ = server.read(wid, "field")
        np.testing.assert_array_equal(field, before)
    server.http.delete(f"/v1/worlds/{wid}")


NAN, INF = float("nan"), float("inf")
# (body, the field its 422 names); sent in msgpack, which carries NaN and infinities.
BAD_OPTIONS = [
    ({"metric": "chebyshev"}, "metric"), ({"metric": 1}, "metric"),
    ({"signed": "true"}, "signed"), ({"signed": 1}, "signed"), ({"signed": "yes"}, "signed"),
    ({"voxel_size": 0}, "voxel_size"), ({"voxel_size": -1.0}, "voxel_size"), ({"voxel_size": NAN}, "voxel_size"),
    ({"voxel_size": INF}, "voxel_size"), ({"voxel_size": "1.5"}, "voxel_size"), ({"voxel_size": True}, "voxel_size"),
    ({"origin": [0.0, 0.0]}, "origin"), ({"origin": [0.0, 0.0, 0.0, 0.0]}, "origin"),
    ({"origin": [NAN, 0.0, 0.0]}, "origin"), ({"origin": [0.0, INF, 0.0]}, "origin"),
    ({"origin": ["1", 0, 0]}, "origin"), ({"origin": "0,0,0"}, "origin"),
    ({"palette": [[0, 0, 0]] * 254}, "palette"), ({"palette": [[0, 0, 0]] * 256}, "palette"),
    ({"palette": "red"}, "palette"), ({"palette": [[0, 0]] * 255}, "palette"),
    ({"palette": [[0, 0, 256]] * 255}, "palette"), ({"palette": [[0, -1, 0]] * 255}, "palette"),
    ({"palette": [[0.5, 0, 0]] * 255}, "palette"),
    ({"metric": "euclidean", "algorithm": "jfa"}, "algorithm"),
    ({"signed": True, "algorithm": "fim"}, "algorithm"),
    ({"metric": "euclidean", "focus": {"center": [0, 0, 0], "size": [1, 1, 1]}}, "focus"),
    ({"signed": True, "borders": "padded", "algorithm": "fim"}, "algorithm"),
]


def refused(r, field: str) -> None:
    assert r.status_code == 422, r.text
    assert r.json()["error"]["code"] == "invalid_input"
    assert field in r.json()["error"]["message"], r.text


@pytest.mark.parametrize("body,field", BAD_OPTIONS, ids=[f"{f}-{i}" for i, (_, f) in enumerate(BAD_OPTIONS)])
def test_bad_field_options_are_refused_naming_the_field(server, body, field):
    wid = server.create_world(size=list(SIZE), chunk_size=8, max_distance=CAP)["id"]
    version = server.edit(wid, [{"op": "box", "min": [2, 2, 2], "max": [9, 5, 6], "colour": 40}])
    server.read(wid, "field", min_version=version)
    worlds = server.http.get("/v1/worlds").json()["worlds"]
    before = server.http.get(f"/v1/worlds/{wid}").json()
    field_before, _ = server.read(wid, "field")

    refused(server.post("/v1/worlds", {"size": list(SIZE), "chunk_size": 8, **body}), field)
    r = server.http.request("PATCH", f"/v1/worlds/{wid}", content=wire.encode(body),
                            headers={"content-type": wire.CONTENT_TYPE})
    refused(r, field)

    assert server.http.get("/v1/worlds").json()["worlds"] == worlds
    assert server.http.get(f"/v1/worlds/{wid}").json() == before
    field_after, _ = server.read(wid, "field")
    np.testing.assert_array_equal(field_after, field_before)
    server.http.delete(f"/v1/worlds/{wid}")


def test_a_sparse_worlds_algorithm_and_cap_are_fixed(server):
    wid = server.create_world(size=list(SIZE), chunk_size=8, storage="sparse", metric="euclidean")["id"]
    before = server.http.get(f"/v1/worlds/{wid}").json()
    for body, field in (({"max_distance": 9}, "max_distance"), ({"algorithm": "exact", "metric": "manhattan"},
                                                                 "algorithm")):
        refused(server.http.patch(f"/v1/worlds/{wid}", json=body), field)
        assert server.http.get(f"/v1/worlds/{wid}").json() == before
    r = server.http.post("/v1/worlds", json={"size": [64, 32, 64], "storage": "sparse", "metric": "euclidean",
                                             "generate": {"kind": "terrain"}})
    refused(r, "generate")
    server.http.delete(f"/v1/worlds/{wid}")


def recv(ws) -> dict:
    return wire.decode(ws.recv(timeout=20))


def test_a_euclidean_world_streams_float32_chunks(server, ref):
    wid = server.create_world(size=list(SIZE), chunk_size=8, max_distance=CAP, metric="euclidean")["id"]
    voxels = np.zeros(SIZE[::-1], np.uint8)
    with websockets.sync.client.connect(server.ws_url + f"/v1/worlds/{wid}/stream") as ws:
        ws.send(wire.encode({"type": "subscribe", "id": "d", "min": [0, 0, 0], "max": list(SIZE)}))
        assert recv(ws) == {"type": "subscribed", "id": "d", "min": [0, 0, 0], "max": list(SIZE), "chunk_size": 8,
                            "format": "distance", "dtype": "float32", "content": "distance",
                            "metric": "euclidean", "signed": False}
        local = np.zeros(SIZE[::-1], np.float32)
        frame = recv(ws)
        assert frame["type"] == "chunks" and frame["version"] == 0
        for chunk in frame["chunks"]:
            data = wire.unpack_array(chunk["data"])
            assert data.dtype == np.float32
            x, y, z = chunk["origin"]
            local[z:z + 8, y:y + 8, x:x + 8] = data
        assert (local == CAP).all()

        batch = [{"op": "sphere", "center": [11, 7, 8], "radius": 3.5, "colour": 60}]
        ws.send(wire.encode({"type": "edits", "id": 1, "edits": batch}))
        ref.apply(voxels, batch)
        while True:  # the ack and the changed chunks, in either order
            message = recv(ws)
            if message["type"] == "ack":
                assert message["version"] == 1
                continue
            assert message["type"] == "chunks"
            for chunk in message["chunks"]:
                data = wire.unpack_array(chunk["data"])
                assert data.dtype == np.float32
                x, y, z = chunk["origin"]
                local[z:z + 8, y:y + 8, x:x + 8] = data
            if message["version"] == 1:
                break
        np.testing.assert_allclose(local, field_distances(voxels, "euclidean", False, CAP), rtol=0, atol=1e-5)

        ws.send(wire.encode({"type": "subscribe", "id": "p", "min": [0, 0, 0], "max": [8, 8, 8],
                             "format": "packed"}))
        message = recv(ws)
        while message["type"] != "subscribed":  # an ack or chunks of the first subscription may come first
            message = recv(ws)
        assert (message["dtype"], message["content"], message["metric"]) == ("uint16", "squared_distance",
                                                                              "euclidean")
    server.http.delete(f"/v1/worlds/{wid}")
