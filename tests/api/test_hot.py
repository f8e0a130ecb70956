"""The short way for the hot routes (``sdfserver/api/hot.py``) answers exactly as the full
app does, and leaves to the full app every request it should not judge."""

from __future__ import annotations

import asyncio
from urllib.parse import parse_qsl

import httpx
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from sdfserver import wire
from sdfserver.api.app import create_app
from sdfserver.api.hot import HotRoutes, query_pairs
from sdfserver.engine import Engine
from sdfserver.settings import Settings

KEY = "hot-route-key-of-the-test"
MSGPACK = {"content-type": wire.CONTENT_TYPE, "accept": wire.CONTENT_TYPE}


class Spy:
    """The full app, noting each HTTP request that reaches it."""

    def __init__(self, app):
        self.app, self.seen = app, []
        self.state = app.state  # what the short way reads (request.app.state)

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            self.seen.append((scope["method"], scope["path"], scope["query_string"]))
        await self.app(scope, receive, send)


def test_hot_routes_answer_as_the_full_app(gpu):
    engine = Engine(gpu)
    app = create_app(Settings(api_keys=f"player:{KEY}", max_ops_per_batch=4), engine)
    spy = Spy(app)
    engine.start(warm_up=False)
    auth = {"authorization": f"Bearer {KEY}"}
    rng = np.random.default_rng()

    async def scenario():
        full = httpx.AsyncClient(transport=httpx.ASGITransport(app=app), base_url="http://t", headers=auth)
        hot = httpx.AsyncClient(transport=httpx.ASGITransport(app=HotRoutes(spy)), base_url="http://t",
                                headers=auth)
        async with full, hot:
            world = (await full.post("/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8})).json()["id"]
            hot_requests = []
            for _ in range(3):  # the same valid batch through each: versions follow on
                lo = rng.integers(0, 12, 3).tolist()
                box = {"op": "box", "min": lo, "max": [v + 4 for v in lo], "colour": int(rng.integers(1, 256))}
                a = await full.post(f"/v1/worlds/{world}/edits", json={"edits": [box]})
                b = await hot.post(f"/v1/worlds/{world}/edits", content=wire.encode({"edits": [box]}),
                                   headers=MSGPACK)
                assert a.status_code == b.status_code == 200
                assert wire.decode(b.content)["version"] == a.json()["version"] + 1
            hot_requests.append(("POST", f"/v1/worlds/{world}/edits"))
            same = [  # (method, path, kwargs): answered alike whichever way they go
                ("POST", f"/v1/worlds/{world}/edits", {"json": {"edits": [{"op": "sphere"}]}}),
                ("POST", f"/v1/worlds/{world}/edits", {"json": {"edits": [], "extra": 1}}),
                ("POST", f"/v1/worlds/{world}/edits", {"json": {"edits": [{"op": "box"}] * 5}}),
                ("POST", f"/v1/worlds/{world}/edits", {"content": b"{not json"}),
                ("POST", f"/v1/worlds/{world}/edits", {"content": b"x", "headers": {"content-type": "text/plain"}}),
                ("POST", "/v1/worlds/nowhere/edits", {"json": {"edits": []}}),
                ("POST", f"/v1/worlds/{world}/edits", {"json": {"edits": []}, "headers": {"authorization": "Bearer x"}}),
                ("GET", f"/v1/worlds/{world}/field", {"params": {"min": "0,0,0", "max": "4,4,4"}}),
                ("GET", f"/v1/worlds/{world}/field", {"params": {"min": "0,0,0", "max": "16,16,16", "format": "packed"},
                                                      "headers": {"accept": "application/octet-stream"}}),
                ("GET", f"/v1/worlds/{world}/field", {"params": {"min": "0,0"}}),
                ("GET", f"/v1/worlds/{world}/field", {"params": {"min": "0,0,0"}}),
                ("GET", f"/v1/worlds/{world}/field", {"params": {"min": "0,0,0", "max": "99,99,99"}}),
                ("GET", "/v1/worlds/nowhere/field", {}),
                ("POST", f"/v1/worlds/{world}/query", {"json": {"points": [[1, 1, 1], [2.5, 3, 4.25]]}}),
                ("POST", f"/v1/worlds/{world}/query", {"json": {"spheres": [[8, 8, 8, 2]]},
                                                       "params": {"min_version": "1"}}),
                ("POST", f"/v1/worlds/{world}/query",
                 {"content": wire.encode({"rays": np.array([[0.5, 0.5, 0.5, 1, 0, 0, 20]], np.float32)}),
                  "headers": MSGPACK}),
                ("POST", f"/v1/worlds/{world}/query", {"json": {"points": [[99, 0, 0]]}}),
                ("POST", f"/v1/worlds/{world}/query", {"json": {"points": []}}),
                ("POST", f"/v1/worlds/{world}/query", {"content": b"{not json"}),
                ("POST", "/v1/worlds/nowhere/query", {"json": {"points": [[1, 1, 1]]}}),
                ("POST", f"/v1/worlds/{world}/query", {"json": {"points": [[1, 1, 1]]},
                                                       "headers": {"authorization": "Bearer x"}}),
            ]
            for method, path, kwargs in same:
                a = await full.request(method, path, **kwargs)
                b = await hot.request(method, path, **kwargs)
                assert (b.status_code, b.headers.get("content-type"), b.content) == \
                       (a.status_code, a.headers.get("content-type"), a.content), (method, path, kwargs)
                hot_requests.append((method, path))
            assert not [s for s in spy.seen if (s[0], s[1]) in hot_requests], spy.seen

            left_to_the_app = [  # its validation, its other methods and routes
                ("GET", f"/v1/worlds/{world}/field", {"params": {"format": "dense"}}),
                ("GET", f"/v1/worlds/{world}/field", {"params": {"min_version": "-1"}}),
                ("GET", f"/v1/worlds/{world}/field", {"params": {"colour": "1"}}),
                ("GET", f"/v1/worlds/{world}/field", {"params": [("format", "packed"), ("format", "distance")]}),
                ("PUT", f"/v1/worlds/{world}/edits", {}),
                ("POST", f"/v1/worlds/{world}/query", {"json": {"points": [[1, 1, 1]]},
                                                       "params": {"min_version": "-1"}}),
                ("POST", f"/v1/worlds/{world}/query", {"json": {"points": [[1, 1, 1]]}, "params": {"x": "1"}}),
                ("GET", f"/v1/worlds/{world}/query", {}),
                ("POST", f"/v1/worlds/{world}/edits", {"json": {"edits": []}, "headers": {"upgrade": "websocket"}}),
                ("GET", f"/v1/worlds/{world}", {}),
            ]
            for method, path, kwargs in left_to_the_app:
                before = len(spy.seen)
                a = await full.request(method, path, **kwargs)
                b = await hot.request(method, path, **kwargs)
                assert (b.status_code, b.content) == (a.status_code, a.content), (method, path, kwargs)
                assert len(spy.seen) == before + 1 and spy.seen[-1][:2] == (method, path)

    try:
        asyncio.run(scenario())
    finally:
        engine.stop()


@given(st.text(alphabet="ab=&%+,;2cCE8F", max_size=40))
def test_query_pairs_are_parse_qsls(query):
    assert query_pairs(query) == parse_qsl(query, keep_blank_values=True)


def test_query_pairs_of_a_game_clients_field_read():
    query = "min=0%2C0%2C0&max=16%2c16%2C16&format=distance&min_version=7&x=%E2%82%AC+1"
    assert query_pairs(query) == parse_qsl(query, keep_blank_values=True)
    assert dict(query_pairs(query))["max"] == "16,16,16"
