"""What the protocol promises a hostile client: 405 answers carry Allow (TRACE included), the
OpenAPI schema documents every error status a route answers, and gauges return to zero when
their cause goes away."""

from __future__ import annotations

import contextlib
import re
import time

from websockets.sync.client import connect

from sdfserver import wire

from hostile_server import error_of


def test_a_method_a_path_does_not_take_is_405_with_allow(start_server):
    server = start_server()
    world = server.new_world()
    for method, path in (("TRACE", "/v1/worlds"), ("TRACE", f"/v1/worlds/{world}"), ("PUT", "/v1/worlds"),
                         ("TRACE", "/readyz"), ("DELETE", f"/v1/worlds/{world}/render")):
        r = server.http.request(method, path)
        assert error_of(r) == (405, "method_not_allowed"), (method, path, r.text)
        allowed = {m.strip() for m in r.headers["allow"].split(",")}
        assert allowed and method not in allowed, (method, path, allowed)


def test_the_openapi_documents_every_error_status(start_server):
    server = start_server()
    schema = server.http.get("/openapi.json").json()
    for path, operations in schema["paths"].items():
        for method, operation in operations.items():
            statuses = set(operation["responses"])
            if path.startswith("/v1/"):
                assert {"401", "404", "422", "429", "500", "503"} <= statuses, (method, path, statuses)
                if method in ("post", "patch"):
                    assert "413" in statuses, (method, path)
                for status in statuses - {"200", "201", "204"}:
                    ref = operation["responses"][status]["content"]["application/json"]["schema"]["$ref"]
                    assert ref == "#/components/schemas/Error", (method, path, status)


def pending_bytes(server) -> float:
    text = server.http.get("/metrics").text
    return float(re.search(r"^sdfserver_stream_pending_bytes (\S+)$", text, re.M).group(1))


def test_the_pending_bytes_gauge_returns_to_zero(start_server):
    server = start_server("--max-world-voxels", str(1 << 21), "--memory-budget-bytes", str(96 << 20))
    world = server.new_world(size=[128, 128, 128], chunk_size=16)
    url = server.ws_url + f"/v1/worlds/{world}/stream"
    with contextlib.ExitStack() as stack:
        sockets = [stack.enter_context(connect(url, max_size=None)) for _ in range(3)]  # never read
        for i, ws in enumerate(sockets):
            ws.send(wire.encode({"type": "subscribe", "id": i, "min": [0, 0, 0], "max": [128, 128, 128],
                                 "format": "packed"}))
        for colour in range(1, 41):  # every chunk changes, again and again, until the sockets are full
            box = {"op": "box", "min": [0, 0, 0], "max": [128, 128 - colour % 8 - 1, 128], "colour": colour}
            assert server.http.post(f"/v1/worlds/{world}/edits", json={"edits": [box]}).status_code == 200
            server.http.get(f"/v1/worlds/{world}/field?min=0,0,0&max=1,1,1&min_version={colour}")
            if colour >= 3 and pending_bytes(server) > 0:
                break
        assert pending_bytes(server) > 0  # their mailboxes hold what the sockets did not take
    deadline = time.monotonic() + 10
    while pending_bytes(server) > 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert pending_bytes(server) == 0
