"""sdfclient's retries, user agent and creation options over httpx.MockTransport: which refusals
are sent again, after how long, and which never are."""

from __future__ import annotations

import asyncio
import itertools

import httpx
import numpy as np
import pytest

import sdfclient
from sdfclient import _protocol, _wire, edits
from sdfclient.errors import NotReady, RateLimited, WritesDisabled

WORLD = {"id": "w", "size": [32, 32, 32], "chunk_size": 16, "max_distance": 255, "algorithm": "exact",
         "version": 1, "field_version": 1}


def ok(body: dict, status: int = 200) -> httpx.Response:
    return httpx.Response(status, content=_wire.encode(body), headers={"content-type": "application/msgpack"})


def refused(status: int, code: str, retry_after: str | None = "0") -> httpx.Response:
    headers = {} if retry_after is None else {"retry-after": retry_after}
    return httpx.Response(status, json={"error": {"code": code, "message": "later"}}, headers=headers)


class Script:
    """Answers each request with the next of ``answers`` (the last one again once they run out)."""

    def __init__(self, *answers: httpx.Response):
        self.answers = list(answers)
        self.requests: list[httpx.Request] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.requests.append(request)
        return self.answers[min(len(self.requests), len(self.answers)) - 1]


@pytest.fixture
def waits(monkeypatch) -> list[float]:
    """The blocking client's waits, recorded instead of slept; no jitter."""
    slept: list[float] = []
    monkeypatch.setattr(sdfclient.client.time, "sleep", slept.append)
    monkeypatch.setattr(_protocol.random, "random", lambda: 0.0)
    return slept


def client(script: Script, **kwargs) -> sdfclient.Client:
    return sdfclient.Client("http://sdf.test", transport=httpx.MockTransport(script), **kwargs)


def test_every_request_names_the_client_and_its_version():
    script = Script(ok({"worlds": []}))
    with client(script) as c:
        c.list_worlds()
    assert script.requests[0].headers["user-agent"] == f"sdfclient/{sdfclient.__version__}"
    assert sdfclient.__version__.count(".") >= 1


def test_a_429_waits_the_servers_retry_after_then_doubles(waits):
    script = Script(refused(429, "rate_limited", "2"), refused(429, "rate_limited", "2"), ok(WORLD))
    with client(script) as c:
        assert c.get_world("w").id == "w"
    assert len(script.requests) == 3 and waits == [2.0, 4.0]


def test_retries_run_out_and_the_last_refusal_is_raised(waits):
    script = Script(refused(429, "rate_limited", "1"))
    with client(script, retries=3) as c:
        with pytest.raises(RateLimited) as caught:
            c.get_world("w")
    assert len(script.requests) == 4 and waits == [1.0, 2.0, 4.0]
    assert caught.value.retry_after_s == 1.0


@pytest.mark.parametrize("retry_after", [None, "60"])
def test_no_retry_without_retry_after_or_past_the_longest_wait(waits, retry_after):
    script = Script(refused(429, "rate_limited", retry_after), ok(WORLD))
    with client(script, max_retry_wait_s=30) as c:
        with pytest.raises(RateLimited):
            c.get_world("w")
    assert len(script.requests) == 1 and waits == []


def test_retries_zero_never_sends_again(waits):
    script = Script(refused(503, "not_ready"), ok(WORLD))
    with client(script, retries=0) as c:
        with pytest.raises(NotReady):
            c.get_world("w")
    assert len(script.requests) == 1


def test_a_503_is_retried_only_where_sending_twice_does_no_harm(waits):
    batch = [edits.sphere((4, 4, 4), 2)]
    # reads: sent again
    script = Script(refused(503, "version_not_reached"), ok({"origin": [0, 0, 0], "version": 2,
                                                             "data": np.zeros((1, 1, 1), np.uint8)}))
    with client(script) as c:
        assert c.read_field("w", min_version=2).version == 2
    assert len(script.requests) == 2
    # a creation, an import, a deletion and an edit batch without a key may have taken effect: never
    for call in (lambda c: c.create_world((32, 32, 32)), lambda c: c.import_world(np.zeros((16, 16, 16), np.uint8)),
                 lambda c: c.delete_world("w"), lambda c: c.edit("w", batch)):
        script = Script(refused(503, "not_ready"), ok(WORLD, 201))
        with client(script) as c, pytest.raises(NotReady):
            call(c)
        assert len(script.requests) == 1
    # an edit batch with an Idempotency-Key is applied once however often it is sent
    script = Script(refused(503, "world_fenced"), ok({"version": 7}))
    with client(script) as c:
        assert c.edit("w", batch, idempotency_key="batch-0001") == 7
    assert [r.headers["idempotency-key"] for r in script.requests] == ["batch-0001"] * 2
    assert script.requests[0].content == script.requests[1].content
    # a refused rate is refused before anything happens: any call is sent again
    script = Script(refused(429, "rate_limited"), ok(WORLD, 201))
    with client(script) as c:
        assert c.create_world((32, 32, 32)).id == "w"
    assert len(script.requests) == 2


def test_writes_disabled_is_never_retried(waits):
    script = Script(refused(503, "writes_disabled", "1"), ok({"version": 2}))
    with client(script) as c:
        with pytest.raises(WritesDisabled):
            c.edit("w", [edits.box((0, 0, 0), (1, 1, 1))], idempotency_key="k")
    assert len(script.requests) == 1 and waits == []


def test_a_bad_idempotency_key_or_retry_setting_fails_before_sending():
    script = Script(ok({"version": 1}))
    with client(script) as c:
        for key in ("", "x" * 129, "caf\u00e9", "tab\there"):
            with pytest.raises(ValueError):
                c.edit("w", [edits.box((0, 0, 0), (1, 1, 1))], idempotency_key=key)
    assert script.requests == []
    for bad in ({"retries": -1}, {"retries": 1.5}, {"max_retry_wait_s": -1.0}):
        with pytest.raises(ValueError):
            client(script, **bad)


def test_async_client_retries_too():
    script = Script(refused(503, "not_ready"), refused(429, "rate_limited"), ok(WORLD))

    async def run():
        async with sdfclient.AsyncClient("http://sdf.test", transport=httpx.MockTransport(script)) as c:
            return await c.get_world("w")

    assert asyncio.run(run()).id == "w" and len(script.requests) == 3
    assert all(r.headers["user-agent"] == f"sdfclient/{sdfclient.__version__}" for r in script.requests)


def test_creation_and_import_options_reach_the_server():
    script = Script(ok({**WORLD, "storage": "sparse"}, 201))
    terrain = {"kind": "terrain", "seed": 7, "cave_depth": 20.0}
    with client(script) as c:
        made = c.create_world((64, 64, 64), storage="sparse", generate=terrain, metric="manhattan")
        imported = c.import_world(np.ones((16, 16, 16), np.uint8), storage="sparse", chunk_size=16)
        with pytest.raises(ValueError):
            c.import_world(np.ones((16, 16, 16), np.uint8), storage="bricks")
        with pytest.raises(ValueError):
            c.create_world((64, 64, 64), storage="sparse", brick=8)
    body = _wire.decode(script.requests[0].content)
    assert body["storage"] == "sparse" and body["generate"] == terrain and body["metric"] == "manhattan"
    assert dict(script.requests[1].url.params) == {"format": "npy", "chunk_size": "16", "storage": "sparse"}
    assert made.storage == imported.storage == "sparse" and len(script.requests) == 2


@pytest.mark.parametrize("status", [429, 503])
def test_the_wait_grows_with_jitter_bounded(monkeypatch, status):
    draws = itertools.cycle([0.0, 1.0])
    monkeypatch.setattr(_protocol.random, "random", lambda: next(draws))
    call = _protocol.get_world("w")
    response = httpx.Response(status, headers={"retry-after": "1"}, request=httpx.Request("GET", "http://x/"))
    assert _protocol.retry_delay(call, response, 0, 30.0) == 1.0
    assert _protocol.retry_delay(call, response, 1, 30.0) == 2.0 * (1 + _protocol.JITTER)
    assert _protocol.retry_delay(call, response, 5, 30.0) is None  # 32 s: past the longest wait
