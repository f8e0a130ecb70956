"""POST /v1/worlds/{id}/query in world units: points, spheres and rays, against NumPy references
computed from the world's voxels (SciPy's distance transforms, capped), for both metrics, signed
and unsigned, and worlds placed with a voxel size and an origin; the requests it refuses; and the
examples of docs/api.md's query section, run as written."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time

import numpy as np
import pytest
from references import field_distances

from sdfserver import wire
from server_process import ROOT, checkout_env

JS = {"content-type": "application/json"}


def trilinear(d: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The interpolant of (z, y, x) centre values at (N, 3) centre coordinates (x, y, z), clamped
    to the outermost centres, and its gradient in the cell holding the clamped point."""
    hi = np.array(d.shape[::-1]) - 1
    q = np.clip(q, 0, hi)
    a = np.minimum(np.floor(q).astype(int), np.maximum(hi - 1, 0))
    b = np.minimum(a + 1, hi)
    f = q - a
    corner = {}
    for cx in (0, 1):
        for cy in (0, 1):
            for cz in (0, 1):
                x, y, z = (b if cx else a)[:, 0], (b if cy else a)[:, 1], (b if cz else a)[:, 2]
                corner[cx, cy, cz] = d[z, y, x]
    w = {0: 1 - f, 1: f}
    value = sum(corner[c] * w[c[0]][:, 0] * w[c[1]][:, 1] * w[c[2]][:, 2] for c in corner)
    gradient = np.stack([
        sum((corner[1, cy, cz] - corner[0, cy, cz]) * w[cy][:, 1] * w[cz][:, 2] for cy in (0, 1) for cz in (0, 1)),
        sum((corner[cx, 1, cz] - corner[cx, 0, cz]) * w[cx][:, 0] * w[cz][:, 2] for cx in (0, 1) for cz in (0, 1)),
        sum((corner[cx, cy, 1] - corner[cx, cy, 0]) * w[cx][:, 0] * w[cy][:, 1] for cx in (0, 1) for cy in (0, 1)),
    ], axis=1)
    return value, gradient


def ask(server, world_id: str, body: dict, version: int = 0) -> dict:
    r = server.post(f"/v1/worlds/{world_id}/query?min_version={version}", body)
    assert r.status_code == 200, r.text
    return wire.decode_arrays(wire.decode(r.content))


def scene(server, rng, size, cap, **options) -> tuple[str, int, np.ndarray]:
    """A world with a floor, a sphere and a box; its id, version and voxels (z, y, x)."""
    wid = server.create_world(size=list(size), chunk_size=8, max_distance=cap, **options)["id"]
    centre = [int(v) for v in rng.integers(4, np.array(size) - 4)]
    version = server.edit(wid, [
        {"op": "box", "min": [0, 0, 0], "max": [size[0], 2, size[2]], "colour": 3},
        {"op": "sphere", "center": centre, "radius": float(rng.integers(2, 5)) + 0.5, "colour": 77},
        {"op": "box", "min": [2, 4, 2], "max": [6, 9, 5], "colour": 200}])
    voxels, _ = server.read(wid, "voxels", min_version=version)
    return wid, version, voxels


PLACES = [(1.0, (0.0, 0.0, 0.0)), (0.25, (-3.5, 1.25, 10.0))]


@pytest.mark.parametrize("metric", ["manhattan", "euclidean"])
@pytest.mark.parametrize("signed", [False, True], ids=["unsigned", "signed"])
@pytest.mark.parametrize("voxel_size,origin", PLACES, ids=["unit", "placed"])
def test_points_match_the_interpolated_reference(server, metric, signed, voxel_size, origin):
    rng = np.random.default_rng()
    size, cap = (24, 16, 32), 6
    wid, version, voxels = scene(server, rng, size, cap, metric=metric, signed=signed, voxel_size=voxel_size,
                                 origin=list(origin))
    d = field_distances(voxels, metric, signed, cap)
    v = rng.uniform(0, 1, (600, 3)) * np.array(size)  # voxel coordinates
    v[:8] = np.array([[0, 0, 0], [0.2, 0.3, 0.1], [23.9, 15.9, 31.9], [3.5, 6.5, 3.5],
                      [10.5, 1.5, 8.5], [10.5, 2.5, 8.5], [12.0, 10.0, 8.0], [0.5, 15.7, 7.25]])
    points = (np.asarray(origin) + v * voxel_size).astype(np.float32)
    v = (points.astype(np.float64) - origin) / voxel_size  # what the server sees
    answer = ask(server, wid, {"points": points}, version)
    assert answer["version"] >= version and answer["distances"].dtype == np.float32
    value, gradient = trilinear(d, v - 0.5)
    np.testing.assert_allclose(answer["distances"], value * voxel_size, atol=2e-4 * cap * max(voxel_size, 1))
    # The gradient jumps across cell boundaries: compare away from them.
    q = np.clip(v - 0.5, 0, np.array(size) - 1)
    clear = (np.abs(q - np.round(q)) > 1e-3).all(axis=1) | (q == np.array(size) - 1).any(axis=1)
    np.testing.assert_allclose(answer["gradients"][clear], gradient[clear], atol=1e-3)
    cell = np.floor(v).astype(int)
    inner = (np.abs(v - np.round(v)) > 1e-4).all(axis=1)
    np.testing.assert_array_equal(answer["colours"][inner], voxels[cell[inner, 2], cell[inner, 1], cell[inner, 0]])
    assert (answer["colours"] > 0).any() and (answer["colours"] == 0).any()
    if signed:
        assert (answer["distances"][answer["colours"] > 0] < 0).mean() > 0.5
    else:
        assert (answer["distances"] >= 0).all()
    # JSON: the same numbers, as lists.
    js = server.http.post(f"/v1/worlds/{wid}/query", json={"points": points[:5].tolist()})
    assert js.status_code == 200, js.text
    np.testing.assert_allclose(js.json()["distances"], answer["distances"][:5])
    assert js.json()["colours"] == answer["colours"][:5].tolist()
    server.http.delete(f"/v1/worlds/{wid}")


def test_a_voxel_centre_gives_that_voxels_distance(server):
    """voxel_size 1, origin 0: the centre of a voxel answers the voxel's own (Manhattan) distance."""
    rng = np.random.default_rng()
    wid, version, voxels = scene(server, rng, (16, 16, 16), 8)
    d = field_distances(voxels, "manhattan", False, 8)
    cells = rng.integers(0, 16, (300, 3))
    answer = ask(server, wid, {"points": (cells + 0.5).astype(np.float32)}, version)
    np.testing.assert_array_equal(answer["distances"], d[cells[:, 2], cells[:, 1], cells[:, 0]])
    np.testing.assert_array_equal(answer["colours"], voxels[cells[:, 2], cells[:, 1], cells[:, 0]])
    server.http.delete(f"/v1/worlds/{wid}")


@pytest.mark.parametrize("metric,signed", [("manhattan", False), ("euclidean", True)])
def test_sphere_clearances_and_directions(server, metric, signed):
    rng = np.random.default_rng()
    size, cap, voxel_size, origin = (24, 16, 32), 6, 0.5, np.array([2.0, -1.0, 0.5])
    wid, version, voxels = scene(server, rng, size, cap, metric=metric, signed=signed, voxel_size=voxel_size,
                                 origin=origin.tolist())
    d = field_distances(voxels, metric, signed, cap)
    v = rng.uniform(0, 1, (400, 3)) * np.array(size)
    radii = rng.uniform(0, 2, 400)
    spheres = np.column_stack([origin + v * voxel_size, radii]).astype(np.float32)
    v = (spheres[:, :3].astype(np.float64) - origin) / voxel_size
    answer = ask(server, wid, {"spheres": spheres}, version)
    value, gradient = trilinear(d, v - 0.5)
    np.testing.assert_allclose(answer["clearances"], value * voxel_size - spheres[:, 3], atol=2e-3)
    norm = np.linalg.norm(gradient, axis=1)
    q = np.clip(v - 0.5, 0, np.array(size) - 1)
    clear = (np.abs(q - np.round(q)) > 1e-3).all(axis=1) & (norm > 1e-3)
    np.testing.assert_allclose(answer["directions"][clear], gradient[clear] / norm[clear, None], atol=1e-3)
    lengths = np.linalg.norm(answer["directions"], axis=1)
    assert np.all((np.abs(lengths - 1) < 1e-4) | (lengths == 0))
    assert (answer["clearances"] < 0).any() and (answer["clearances"] > 0).any()
    server.http.delete(f"/v1/worlds/{wid}")


@pytest.mark.parametrize("metric", ["manhattan", "euclidean"])
@pytest.mark.parametrize("voxel_size,origin", PLACES, ids=["unit", "placed"])
def test_rays_hit_a_wall(server, metric, voxel_size, origin):
    """A wall x in [20, 24) voxels across the whole world: rays from either side, slanted, too
    short, turned away, from inside it and from outside the world."""
    size = (32, 16, 16)
    wid = server.create_world(size=list(size), chunk_size=8, max_distance=10, metric=metric,
                              voxel_size=voxel_size, origin=list(origin))["id"]
    version = server.edit(wid, [{"op": "box", "min": [20, 0, 0], "max": [24, 16, 16], "colour": 9}])
    o = np.asarray(origin)
    slant = np.array([1.0, 0.5, 0.2]) / np.linalg.norm([1.0, 0.5, 0.2])
    rays_vox = [  # origin (voxels), direction, max length (voxels); expected t (voxels), normal x, voxel x
        ((2.25, 5.5, 7.5), (1, 0, 0), 100, 17.75, -1, 20),
        ((2.25, 2.5, 3.5), tuple(slant * 3), 100, 17.75 / slant[0], -1, 20),
        ((30.5, 8.5, 8.5), (-2, 0, 0), 100, 6.5, 1, 23),
        ((2.25, 5.5, 7.5), (1, 0, 0), 17.0, None, 0, -1),
        ((2.25, 5.5, 7.5), (-1, 0, 0), 100, None, 0, -1),
        ((21.5, 5.5, 7.5), (0, 1, 0), 100, 0.0, 0, 21),
        ((-10.0, 5.5, 7.5), (1, 0, 0), 100, 30.0, -1, 20),
    ]
    rays = np.array([[*(o + np.array(p) * voxel_size), *dv, length * voxel_size]
                     for p, dv, length, *_ in rays_vox], dtype=np.float32)
    answer = ask(server, wid, {"rays": rays}, version)
    for i, (p, dv, length, t, normal_x, voxel_x) in enumerate(rays_vox):
        assert bool(answer["hits"][i]) == (t is not None), i
        want_t = length if t is None else t
        assert answer["distances"][i] == pytest.approx(want_t * voxel_size, abs=1e-3 * max(voxel_size, 1)), i
        assert answer["normals"][i].tolist() == [normal_x, 0, 0], i
        assert answer["voxels"][i][0] == voxel_x and answer["colours"][i] == (9 if t is not None else 0), i
    assert answer["hits"].dtype == np.uint8  # msgpack: a uint8 blob; JSON: booleans
    js = server.http.post(f"/v1/worlds/{wid}/query", json={"rays": rays[:4].tolist()}).json()
    assert js["hits"] == [True, True, True, False] and js["voxels"][0] == [20, 5, 7]
    server.http.delete(f"/v1/worlds/{wid}")


@pytest.fixture(scope="module")
def placed(server):
    """A 16 x 16 x 16 world at origin (10, 0, 0), voxel size 0.5: its box is [10, 18) x [0, 8) x [0, 8)."""
    wid = server.create_world(size=[16, 16, 16], chunk_size=8, max_distance=8, voxel_size=0.5,
                              origin=[10.0, 0.0, 0.0])["id"]
    server.edit(wid, [{"op": "box", "min": [0, 0, 0], "max": [16, 2, 16], "colour": 1}])
    yield wid
    server.http.delete(f"/v1/worlds/{wid}")


F32 = np.float32
BAD_BODIES = [  # body, status, what the message names
    ({"points": [[11, 2]]}, 422, "points"),
    ({"points": [[11, 2, "x"]]}, 422, "points"),
    ({"points": []}, 422, "points"),
    ({"spheres": None}, 422, "spheres"),
    ({"points": np.zeros((0, 3), F32)}, 422, "points"),
    ({"points": np.array([[11, 2, 3, 4]], F32)}, 422, "points"),
    ({"points": np.array([[11, np.nan, 3]], F32)}, 422, "points"),
    ({"points": np.array([[11, 1, 1], [11, np.inf, 3]], F32)}, 422, "points[1]"),
    ({"points": [[11, 1, 1], [9.9, 1, 1]]}, 422, "points[1]"),
    ({"points": np.array([[11, 1, 1], [12, 1, 8.0]], F32)}, 422, "points[1]"),
    ({"spheres": [[11, 1, 1, -0.5]]}, 422, "spheres[0]"),
    ({"spheres": np.array([[11, 1, 1, np.inf]], F32)}, 422, "spheres[0]"),
    ({"spheres": [[11, 1, 1]]}, 422, "spheres"),
    ({"spheres": [[30, 1, 1, 1]]}, 422, "spheres[0]"),
    ({"rays": [[11, 1, 1, 0, 0, 0, 5]]}, 422, "rays[0]"),
    ({"rays": np.array([[11, 1, 1, 1, 0, 0, 5], [11, 1, 1, 0, 0, 0, 5]], F32)}, 422, "rays[1]"),
    ({"rays": [[11, 1, 1, 1, 0, 0, -5]]}, 422, "rays[0]"),
    ({"rays": np.array([[11, 1, 1, 1, 0, 0]], F32)}, 422, "rays"),
    ({"points": [[11, 1, 1]], "spheres": [[11, 1, 1, 1]]}, 422, "exactly one"),
    ({"points": [[11, 1, 1]], "radius": 2}, 422, "radius"),
    ({"pts": [[11, 1, 1]]}, 422, "pts"),
    ({}, 422, "exactly one"),
    ({"points": [[11.0, 1.0, 1.0]] * 1001}, 413, "1001 points"),
    ({"spheres": np.ones((1001, 4), F32)}, 413, "1001 spheres"),
    ({"rays": np.ones((1001, 7), F32)}, 413, "1001 rays"),
]


@pytest.mark.parametrize("body,status,named", BAD_BODIES, ids=[f"bad{i}" for i in range(len(BAD_BODIES))])
def test_bad_queries_are_refused_naming_the_field(server, placed, body, status, named):
    before = server.state(placed)
    r = server.post(f"/v1/worlds/{placed}/query", body)
    assert r.status_code == status, r.text
    assert named in r.json()["error"]["message"], r.json()
    assert server.state(placed) == before


def test_nan_and_non_objects_in_json(server, placed):
    for content in (b'{"rays": [[11, 1, 1, 1, 0, NaN, 5]]}', b'[[11, 1, 1]]', b'{"points": [[11, 1, Infinity]]}'):
        r = server.http.post(f"/v1/worlds/{placed}/query", content=content, headers=JS)
        assert r.status_code == 422, r.text


def test_the_answer_says_how_long_the_server_took(server, placed):
    """Server-Timing: app;dur=<ms>, the server's own measure (from the route's start to the
    response made), on the short way (hot.py) and through the full app (an unknown parameter,
    which FastAPI ignores); never more than the client's round trip."""
    rows = np.column_stack([np.random.default_rng().uniform(10, 18, 500), np.full((500, 2), 1.0)]).astype(F32)
    for path in (f"/v1/worlds/{placed}/query", f"/v1/worlds/{placed}/query?min_version=1",
                 f"/v1/worlds/{placed}/query?unknown=1"):
        for body, headers in ((wire.encode({"points": rows}), {"content-type": wire.CONTENT_TYPE}),
                              (json.dumps({"spheres": [[11, 1, 1, 0.25]]}).encode(), JS)):
            started = time.perf_counter()
            r = server.http.post(path, content=body, headers=headers)
            round_trip_ms = (time.perf_counter() - started) * 1e3
            assert r.status_code == 200, r.text
            timing = re.fullmatch(r"app;dur=(\d+\.\d{3})", r.headers["server-timing"])
            assert timing, r.headers["server-timing"]
            assert 0 < float(timing[1]) <= round_trip_ms, (timing[1], round_trip_ms)


# -- docs/api.md's examples -------------------------------------------------------------------------

QUERY_SECTION = re.search(r"^## Queries\n(.*?)(?=^## )", (ROOT / "docs" / "api.md").read_text(), flags=re.S | re.M)
EXAMPLES = re.findall(r"^```python\n(.*?)^```", QUERY_SECTION.group(1) if QUERY_SECTION else "", flags=re.S | re.M)


def test_the_query_section_has_an_example_of_each_call():
    assert len(EXAMPLES) == 3
    for call in ("query(", "query_spheres(", "query_rays("):
        assert any(call in block for block in EXAMPLES), call


@pytest.mark.parametrize("block", EXAMPLES, ids=[f"example{i}" for i in range(len(EXAMPLES))])
def test_the_query_examples_run_as_written(server, block):
    """Each example, fed to a fresh interpreter; only the documented address is swapped."""
    assert "http://127.0.0.1:8000" in block
    before = {w["id"] for w in server.http.get("/v1/worlds").json()["worlds"]}
    proc = subprocess.run([sys.executable, "-"], input=block.replace("http://127.0.0.1:8000", server.url),
                          cwd=ROOT, env=checkout_env(ROOT / "clients"), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert {w["id"] for w in server.http.get("/v1/worlds").json()["worlds"]} == before  # it cleans up
