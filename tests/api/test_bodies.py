"""The shortcuts in bodies.py answer exactly as starlette does: the same raw headers, the same JSON
bytes, the same header values."""

from __future__ import annotations

import pytest
from starlette.requests import Request
from starlette.responses import JSONResponse, Response

from sdfserver.api.bodies import JSON_ENCODER, Encoded, header


@pytest.mark.parametrize("status", [200, 201])
@pytest.mark.parametrize("media_type", ["application/msgpack", "application/json", "application/octet-stream"])
def test_encoded_sends_the_headers_of_starlettes_response(status, media_type):
    body = b'{"version":3}'
    assert Encoded(body, media_type, status).raw_headers == Response(body, status, media_type=media_type).raw_headers
    extra = {"X-Sdf-Origin": "0,8,16", "X-Sdf-Version": "7"}
    raw = [(name.lower().encode(), value.encode()) for name, value in extra.items()]
    assert (Encoded(body, media_type, status, headers=raw).raw_headers
            == Response(body, status, headers=extra, media_type=media_type).raw_headers)


def test_the_json_encoder_writes_what_jsonresponse_writes():
    content = {"version": 3, "name": "wörld \u2028", "gradients": [[0.5, -1e-300, 1e300]], "focus": None}
    assert JSON_ENCODER.encode(content).encode() == JSONResponse(content).body
    with pytest.raises(ValueError):
        JSON_ENCODER.encode({"x": float("nan")})


def test_header_finds_what_starlette_finds():
    raw = [(b"accept", b"application/msgpack"), (b"x-tag", b"caf\xe9"), (b"accept", b"application/json")]
    request = Request({"type": "http", "headers": raw})
    for name in ("accept", "x-tag", "content-type"):
        assert header(request, name.encode()) == request.headers.get(name)
