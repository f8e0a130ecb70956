"""Fields read over HTTP equal the SciPy oracle after random edit sequences."""

from __future__ import annotations

import base64

import numpy as np
import pytest

from sdfserver import wire


@pytest.mark.parametrize("size,chunk,cap", [((32, 24, 40), 8, 6), ((32, 32, 32), 16, 255)])
def test_random_edits_match_oracle(server, ref, size, chunk, cap):
    seed = int(np.random.SeedSequence().entropy % 2**32)
    rng = np.random.default_rng(seed)
    world = server.create_world(size=list(size), chunk_size=chunk, max_distance=cap)
    wid = world["id"]
    expected = np.zeros(size[::-1], dtype=np.uint8)
    for i in range(8):
        batch = ref.batch(rng, size, blob=i % 2 == 0)
        version = server.edit(wid, batch, as_json=i % 2 == 1)
        assert version == i + 1
        ref.apply(expected, batch)
        if i % 3 == 2 or i == 7:
            field, msg = server.read(wid, "field", min_version=version)
            assert msg["version"] >= version and msg["origin"] == [0, 0, 0]
            assert msg["dtype"] == "uint8" and msg["shape"] == list(size[::-1])
            np.testing.assert_array_equal(field, ref.distance(expected, cap), err_msg=f"seed {seed}")
            voxels, _ = server.read(wid, "voxels")
            np.testing.assert_array_equal(voxels, expected, err_msg=f"seed {seed}")
    # The packed format carries the voxel's colour in the low byte.
    packed, msg = server.read(wid, "field", format="packed")
    assert msg["dtype"] == "uint16"
    np.testing.assert_array_equal(packed >> 8, ref.distance(expected, cap))
    np.testing.assert_array_equal((packed & 0xFF)[expected > 0], expected[expected > 0])
    server.http.delete(f"/v1/worlds/{wid}")


def test_sub_box_in_every_format(server, ref):
    rng = np.random.default_rng()
    size = (32, 32, 32)
    wid = server.create_world(size=list(size), chunk_size=8, max_distance=10)["id"]
    expected = np.zeros(size[::-1], dtype=np.uint8)
    for _ in range(3):
        batch = ref.batch(rng, size)
        version = server.edit(wid, batch)
        ref.apply(expected, batch)
    oracle = ref.distance(expected, 10)
    lo = [int(v) for v in rng.integers(0, 16, 3)]
    hi = [v + int(rng.integers(1, 16)) for v in lo]
    params = {"min": ",".join(map(str, lo)), "max": ",".join(map(str, hi)), "min_version": version}
    want = oracle[lo[2]:hi[2], lo[1]:hi[1], lo[0]:hi[0]]

    msgpack_field, msg = server.read(wid, "field", **params)
    assert msg["origin"] == lo
    np.testing.assert_array_equal(msgpack_field, want)

    raw = server.http.get(f"/v1/worlds/{wid}/field", params=params, headers={"accept": "application/octet-stream"})
    assert raw.headers["x-sdf-origin"] == ",".join(map(str, lo))
    shape = [int(v) for v in raw.headers["x-sdf-shape"].split(",")]
    assert int(raw.headers["x-sdf-version"]) >= version
    np.testing.assert_array_equal(np.frombuffer(raw.content, raw.headers["x-sdf-dtype"]).reshape(shape), want)

    js = server.http.get(f"/v1/worlds/{wid}/field", params=params, headers={"accept": "application/json"}).json()
    decoded = np.frombuffer(base64.b64decode(js["data"]), js["dtype"]).reshape(js["shape"])
    np.testing.assert_array_equal(decoded, want)
    server.http.delete(f"/v1/worlds/{wid}")


def test_point_query_matches_oracle(server, ref):
    rng = np.random.default_rng()
    size = (32, 32, 32)
    cap = 12
    wid = server.create_world(size=list(size), chunk_size=8, max_distance=cap)["id"]
    expected = np.zeros(size[::-1], dtype=np.uint8)
    batch = [{"op": "sphere", "center": [int(v) for v in rng.integers(8, 24, 3)], "radius": 4.5, "colour": 77},
             {"op": "box", "min": [0, 0, 0], "max": [32, 2, 32], "colour": 3}]
    version = server.edit(wid, batch)
    ref.apply(expected, batch)
    oracle = ref.distance(expected, cap).astype(np.float64)
    # At voxel centres (voxel_size 1, origin 0) the interpolated distance is the voxel's own;
    # tests/api/test_world_queries.py checks points anywhere, spheres and rays.
    v = rng.integers(0, 32, (200, 3))
    r = server.post(f"/v1/worlds/{wid}/query?min_version={version}", {"points": (v + 0.5).astype(np.float32)})
    assert r.status_code == 200, r.text
    answer = wire.decode_arrays(wire.decode(r.content))
    np.testing.assert_array_equal(answer["distances"], oracle[v[:, 2], v[:, 1], v[:, 0]])
    np.testing.assert_array_equal(answer["colours"], expected[v[:, 2], v[:, 1], v[:, 0]])
    # The gradient at a centre: the slope of the cell above it along each axis (below it on the top face).
    grads = []
    for axis in range(3):
        lo = np.minimum(v[:, axis], 30)
        a, b = v.copy(), v.copy()
        a[:, axis], b[:, axis] = lo, lo + 1
        grads.append(oracle[b[:, 2], b[:, 1], b[:, 0]] - oracle[a[:, 2], a[:, 1], a[:, 0]])
    np.testing.assert_allclose(answer["gradients"], np.stack(grads, axis=1), atol=1e-5)
    points = (v + 0.5).astype(np.float32)
    # JSON works too, with lists.
    js = server.http.post(f"/v1/worlds/{wid}/query", json={"points": points[:3].tolist()}).json()
    assert js["distances"] == answer["distances"][:3].tolist()
    server.http.delete(f"/v1/worlds/{wid}")


def test_world_lifecycle(server):
    world = server.create_world(size=[16, 16, 16], chunk_size=8, max_distance=8)
    wid = world["id"]
    assert world["version"] == 0 and world["field_version"] == 0 and world["algorithm"] == "exact"
    assert wid in [w["id"] for w in server.http.get("/v1/worlds").json()["worlds"]]
    server.edit(wid, [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2], "colour": 9}])
    patched = server.http.patch(f"/v1/worlds/{wid}", json={"max_distance": 4, "focus": {"center": [1, 1, 1],
                                                                                          "size": [1, 1, 1]}})
    assert patched.status_code == 200, patched.text
    body = patched.json()
    assert body["max_distance"] == 4 and body["focus"] == {"center": [1, 1, 1], "size": [1, 1, 1]}
    assert body["field_version"] == 1 and body["dirty_chunks"] == 0
    field, _ = server.read(wid, "field")
    assert field.max() == 4 and field[0, 0, 0] == 0
    cleared = server.http.patch(f"/v1/worlds/{wid}", json={"focus": None}).json()
    assert cleared["focus"] is None and cleared["max_distance"] == 4
    assert server.http.delete(f"/v1/worlds/{wid}").status_code == 204
    assert server.http.get(f"/v1/worlds/{wid}").status_code == 404
    msg = wire.decode(server.http.get("/v1/worlds", headers={"accept": wire.CONTENT_TYPE}).content)
    assert wid not in [w["id"] for w in msg["worlds"]]


def test_openapi_and_health(server):
    assert server.http.get("/livez").json() == {"status": "ok"}
    ready = server.http.get("/readyz").json()
    assert ready["status"] == "ready" and ready["device"]
    assert server.http.get("/docs").status_code == 200
    schema = server.http.get("/openapi.json").json()
    assert {"/v1/worlds", "/v1/worlds/{world_id}/edits", "/v1/worlds/{world_id}/field",
            "/v1/worlds/{world_id}/query"} <= set(schema["paths"])
    text = str(schema)
    import re

    for ref in set(re.findall(r"#/components/schemas/(\w+)", text)):
        assert ref in schema["components"]["schemas"], f"dangling $ref {ref}"
    world = server.create_world(size=[16, 16, 16], chunk_size=8)["id"]  # a recompute, whatever ran before
    server.read(world, min_version=server.edit(world, [{"op": "box", "min": [1, 1, 1], "max": [3, 3, 3], "colour": 2}]))
    server.http.delete(f"/v1/worlds/{world}")
    metrics = server.http.get("/metrics").text
    for name in ("sdfserver_edit_batches_total", "sdfserver_recompute_seconds_bucket", "sdfserver_queue_depth",
                 "sdfserver_websocket_clients", "sdfserver_bytes_out_total", "sdfserver_dirty_chunks",
                 "sdfserver_engine_step_seconds_bucket", 'sdfserver_engine_phase_seconds_total{phase="apply"}',
                 'sdfserver_gc_collections_total{generation="2"}',
                 'sdfserver_engine_gc_collections_total{generation="2"}'):
        assert name in metrics
    # The API process and the engine process froze their start-up objects (tens of thousands
    # each) out of the collector.
    for process in ("gc", "engine_gc"):
        frozen = re.search(rf"^sdfserver_{process}_frozen_objects (\S+)$", metrics, re.M)
        assert frozen and float(frozen.group(1)) > 10_000, process


def test_every_answer_type_the_server_negotiates_is_in_its_openapi(server):
    """A msgpack request without an Accept header is answered in msgpack, and a read with no
    Accept header too: the schema documents both, as schemathesis checks (tests/durability)."""
    paths = server.http.get("/openapi.json").json()["paths"]
    r = server.http.post("/v1/worlds", content=wire.encode({"size": [16, 16, 16], "chunk_size": 8}),
                         headers={"content-type": wire.CONTENT_TYPE})
    assert r.status_code == 201 and r.headers["content-type"] == wire.CONTENT_TYPE
    assert wire.CONTENT_TYPE in paths["/v1/worlds"]["post"]["responses"]["201"]["content"]
    world = wire.decode(r.content)["id"]
    for accept in (None, "application/octet-stream", "application/json"):
        read = server.http.get(f"/v1/worlds/{world}/field", headers={"accept": accept} if accept else {})
        assert read.status_code == 200
        documented = paths["/v1/worlds/{world_id}/field"]["get"]["responses"]["200"]["content"]
        assert read.headers["content-type"].split(";")[0] in documented, (accept, read.headers["content-type"])
