"""The fast lane answers exactly as FastAPI's routes do: the same requests, sent to an app with
the lane and to one without it, get the same status, error code and (for successes) body."""

from __future__ import annotations

import asyncio

import httpx
import numpy as np
import pytest

from starlette.datastructures import QueryParams

from sdfserver import wire
from sdfserver.api.app import create_app
from sdfserver.api.fastlane import query_params
from sdfserver.engine import Engine, EngineLimits
from sdfserver.gpu import GpuContext
from sdfserver.settings import Settings

SETTINGS = Settings(persist=False, max_wait_ms=300, max_query_points=50, max_ops_per_batch=8,
                    api_keys="alice:alice-token-0123456789,bob:bob-token-0123456789abc")
ALICE = {"authorization": "Bearer alice-token-0123456789"}
BOB = {"authorization": "Bearer bob-token-0123456789abc"}
MP = {"content-type": wire.CONTENT_TYPE, "accept": wire.CONTENT_TYPE}


def requests(world: str, rng: np.random.Generator) -> list[tuple[str, str, dict]]:
    """(method, path, httpx keyword arguments): good and bad, JSON and msgpack."""
    rows = np.column_stack([rng.integers(0, 16, (20, 3)), rng.integers(1, 256, 20)]).astype(np.uint16)
    sphere = {"op": "sphere", "center": rng.uniform(0, 16, 3).tolist(), "radius": 3.5, "colour": 9}
    base = f"/v1/worlds/{world}"
    return [
        ("POST", f"{base}/edits", {"json": {"edits": [sphere]}, "headers": ALICE}),
        ("POST", f"{base}/edits", {"content": wire.encode({"edits": [{"op": "voxels", "voxels": rows}]}),
                                   "headers": {**ALICE, **MP}}),
        ("GET", f"{base}/field", {"params": {"min_version": 2, "min": "0,0,0", "max": "16,8,4"}, "headers": ALICE}),
        ("GET", f"{base}/field", {"params": {"format": "packed"}, "headers": {**ALICE, **MP}}),
        ("GET", f"{base}/field", {"params": {"format": "distance"}, "headers": {**ALICE, "accept": "application/json"}}),
        ("GET", f"{base}/field", {"params": {"max": "8,8,8", "min": "0,0,0"},
                                  "headers": {**ALICE, "accept": "application/octet-stream"}}),
        ("POST", f"{base}/query", {"json": {"points": [[1.5, 2, 3], [15, 15, 15]]}, "headers": ALICE}),
        ("POST", f"{base}/query", {"params": {"min_version": 2}, "content": wire.encode({"points": rng.uniform(
            0, 15, (5, 3))}), "headers": {**ALICE, **MP}}),
        # failures: each must match FastAPI's status and error code
        ("POST", f"{base}/edits", {"json": {"edits": [sphere]}}),  # no key: 401
        ("POST", f"{base}/edits", {"json": {"edits": [sphere]}, "headers": BOB}),  # another tenant: 404
        ("POST", "/v1/worlds/nope/edits", {"json": {"edits": [sphere]}, "headers": ALICE}),
        ("POST", f"{base}/edits", {"content": b"{not json", "headers": {**ALICE, "content-type": "application/json"}}),
        ("POST", f"{base}/edits", {"content": b"\xc1", "headers": {**ALICE, **MP}}),
        ("POST", f"{base}/edits", {"json": {"edits": [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2],
                                                       "colour": 300}]}, "headers": ALICE}),
        ("POST", f"{base}/edits", {"json": {"edits": [sphere] * 9}, "headers": ALICE}),
        ("POST", f"{base}/edits", {"json": {"edits": [], "x": 1}, "headers": ALICE}),
        ("GET", f"{base}/field", {"params": {"min_version": "abc"}, "headers": ALICE}),
        ("GET", f"{base}/field", {"params": {"min_version": "-1"}, "headers": ALICE}),
        ("GET", f"{base}/field", {"params": {"format": "rgb"}, "headers": ALICE}),
        ("GET", f"{base}/field", {"params": {"min": "0,0,0"}, "headers": ALICE}),
        ("GET", f"{base}/field", {"params": {"min": "0,0,0", "max": "17,1,1"}, "headers": ALICE}),
        ("GET", f"{base}/field", {"params": {"min_version": 99}, "headers": ALICE}),  # 503, after the wait
        ("POST", f"{base}/query", {"json": {"points": [[1, 2]]}, "headers": ALICE}),
        ("POST", f"{base}/query", {"json": {"points": [[1.0, 2.0, 3.0]] * 51}, "headers": ALICE}),
        ("POST", f"{base}/query", {"params": {"min_version": "x"}, "json": {"points": [[1, 2, 3]]},
                                   "headers": ALICE}),
        ("GET", f"{base}/edits", {"headers": ALICE}),  # wrong method: FastAPI's 405 either way
        ("POST", f"{base}/edits/", {"json": {"edits": [sphere]}, "headers": ALICE}),  # not a lane path
    ]


async def run(app, rng_seed: int) -> list[tuple[int, object]]:
    rng = np.random.default_rng(rng_seed)
    out = []
    async with httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://t") as http:
        r = await http.post("/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8, "max_distance": 6},
                            headers=ALICE)
        assert r.status_code == 201, r.text
        for method, path, kwargs in requests(r.json()["id"], rng):
            r = await http.request(method, path, **kwargs)
            if r.status_code >= 400:
                out.append((r.status_code, r.json()["error"]["code"], r.headers.get("retry-after"),
                            r.headers.get("www-authenticate")))
            else:
                out.append((r.status_code, r.headers.get("content-type"), r.content, r.headers.get("x-sdf-version")))
    return out


@pytest.fixture(scope="module")
def gpu():
    return GpuContext.create()


def test_the_lane_answers_as_fastapi_does(gpu):
    seed = int(np.random.SeedSequence().entropy % 2**32)
    answers = []
    for lane in (True, False):
        engine = Engine(gpu, EngineLimits(max_wait_s=0.3))
        app = create_app(SETTINGS, engine, fast_lane=lane)
        engine.start(warm_up=False)
        try:
            answers.append(asyncio.run(run(app, seed)))
        finally:
            engine.stop()
    with_lane, without = answers
    assert len(with_lane) == len(without)
    for i, (a, b) in enumerate(zip(with_lane, without)):
        assert a == b, f"request {i}: lane {a[:2]} != FastAPI {b[:2]}"
    assert [a[0] for a in with_lane[:8]] == [200] * 8  # the good requests did succeed


def test_the_lane_is_on_by_default_and_openapi_still_documents_its_routes():
    app = create_app(Settings(persist=False))
    assert app.lane is not None
    paths = app.openapi()["paths"]
    assert "post" in paths["/v1/worlds/{world_id}/edits"]
    field = paths["/v1/worlds/{world_id}/field"]["get"]
    assert {p["name"] for p in field["parameters"]} >= {"world_id", "min", "max", "format", "min_version"}
    assert "post" in paths["/v1/worlds/{world_id}/query"]


@pytest.mark.parametrize("query", [b"", b"&&", b"min_version", b"min_version=", b"=3", b"min=0,0,0&max=16,8,4",
                                   b"min_version=1&min_version=2", b"min=0%2C0%2C0&format=packed", b"format=a+b",
                                   b"min_version=%zz&x=%C3%A9", b"a=b=c", b"min_version=\xff", b"x=1;format=packed"])
def test_the_lanes_query_string_reads_as_starlettes(query):
    """httpx escapes the commas of min and max; the lean client sends them plain (the lane's fast path)."""
    starlette = QueryParams(query)
    assert query_params({"query_string": query}) == {name: starlette[name] for name in starlette}
