"""Every number a route takes, fed its extremes — 0, -1, 2^31, 2^63, 2^64, 10^400, NaN, ±inf and
deep nesting — through HTTP (JSON and msgpack bodies, query strings) and the WebSocket: each value
outside the field's range gets a 4xx with the one error body (never a 5xx, never a hang), and
the world and the list of worlds are exactly as they were afterwards.

The table lists each route's fields with the range they accept; the values inside it are not
sent (a valid 0 would rightly change the world)."""

from __future__ import annotations

import json
import math
from typing import Any, Callable

import msgpack
import pytest
from websockets.sync.client import connect

from sdfserver import wire

from hostile_server import error_of

NEST = object()  # a value nested thousands of levels deep
LONG = object()  # a flat list of 2,000 zeros: a message that echoed it whole would run to 6,000 characters
EXTREMES = [0, -1, 2 ** 31, 2 ** 63, 2 ** 64, 10 ** 400, math.nan, math.inf, -math.inf, NEST, LONG]
LABELS = {id(NEST): "nest", id(LONG): "long"}
X = "__extreme__"  # where the value goes in a body


def real(lo: float, hi: float) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, (int, float)) and lo <= v <= hi  # NaN and ±inf compare False or beyond


def integer(lo: int, hi: int) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, int) and lo <= v <= hi


NONE: Callable[[Any], bool] = lambda v: False  # noqa: E731  (no extreme is valid here)
INT32 = integer(-2 ** 31, 2 ** 31 - 1)
CAMERA = {"position": [8.5, 30, 40], "target": [8, 4, 8], "width": 16, "height": 12}
BOX = {"op": "box", "min": [0, 0, 0], "max": [4, 4, 4], "colour": 9}
SPHERE = {"op": "sphere", "center": [8, 8, 8], "radius": 3, "colour": 9}
VOXELS = {"op": "voxels", "voxels": [[1, 2, 3, 9]]}

# (name, method, path, body with X where the value goes, the values the field accepts)
BODIES: list[tuple[str, str, str, Any, Callable[[Any], bool]]] = [
    ("create size", "POST", "/v1/worlds", {"size": [X, 16, 16], "chunk_size": 8}, NONE),
    ("create chunk_size", "POST", "/v1/worlds", {"size": [16, 16, 16], "chunk_size": X}, NONE),
    ("create max_distance", "POST", "/v1/worlds", {"size": [16, 16, 16], "max_distance": X}, NONE),
    ("create focus centre", "POST", "/v1/worlds",
     {"size": [16, 16, 16], "chunk_size": 8, "focus": {"center": [X, 0, 0], "size": [1, 1, 1]}}, INT32),
    ("create focus size", "POST", "/v1/worlds",
     {"size": [16, 16, 16], "chunk_size": 8, "focus": {"center": [0, 0, 0], "size": [1, X, 1]}}, NONE),
    ("patch max_distance", "PATCH", "/v1/worlds/{w}", {"max_distance": X}, NONE),
    ("patch focus centre", "PATCH", "/v1/worlds/{w}", {"focus": {"center": [0, X, 0], "size": [1, 1, 1]}},
     INT32),
    ("patch focus size", "PATCH", "/v1/worlds/{w}", {"focus": {"center": [0, 0, 0], "size": [1, 1, X]}}, NONE),
    ("box min", "POST", "/v1/worlds/{w}/edits", {"edits": [{**BOX, "min": [X, 0, 0]}]}, INT32),
    ("box max", "POST", "/v1/worlds/{w}/edits", {"edits": [{**BOX, "max": [4, X, 4]}]}, INT32),
    ("box colour", "POST", "/v1/worlds/{w}/edits", {"edits": [{**BOX, "colour": X}]}, integer(0, 255)),
    ("sphere centre", "POST", "/v1/worlds/{w}/edits", {"edits": [{**SPHERE, "center": [8, 8, X]}]},
     real(-2 ** 31, 2 ** 31 - 1)),
    ("sphere radius", "POST", "/v1/worlds/{w}/edits", {"edits": [{**SPHERE, "radius": X}]}, real(0, 40)),
    ("voxel coordinate", "POST", "/v1/worlds/{w}/edits", {"edits": [{**VOXELS, "voxels": [[X, 2, 3, 9]]}]},
     integer(0, 15)),
    ("voxel colour", "POST", "/v1/worlds/{w}/edits", {"edits": [{**VOXELS, "voxels": [[1, 2, 3, X]]}]},
     integer(0, 255)),
    ("query point", "POST", "/v1/worlds/{w}/query", {"points": [[1, X, 1]]}, real(0, 15.99)),
    ("render position", "POST", "/v1/worlds/{w}/render", {**CAMERA, "position": [X, 30, 40]}, real(-1e6, 1e6)),
    ("render target", "POST", "/v1/worlds/{w}/render", {**CAMERA, "target": [8, X, 8]}, real(-1e6, 1e6)),
    ("render yaw", "POST", "/v1/worlds/{w}/render",
     {"position": [8, 8, 40], "yaw_deg": X, "width": 16, "height": 12}, real(-1e300, 1e300)),
    ("render fov", "POST", "/v1/worlds/{w}/render", {**CAMERA, "fov_y_deg": X}, NONE),
    ("render width", "POST", "/v1/worlds/{w}/render", {**CAMERA, "width": X}, NONE),
    ("render height", "POST", "/v1/worlds/{w}/render", {**CAMERA, "height": X}, NONE),
    ("render sky", "POST", "/v1/worlds/{w}/render", {**CAMERA, "sky_rgb": X}, integer(0, 0xFFFFFF)),
    ("render light", "POST", "/v1/worlds/{w}/render", {**CAMERA, "light": [1, X, 1]}, real(-1e6, 1e6)),
    ("render highlight", "POST", "/v1/worlds/{w}/render", {**CAMERA, "highlight": [X, 1, 1]}, INT32),
    ("render highlight radius", "POST", "/v1/worlds/{w}/render", {**CAMERA, "highlight_radius": X}, real(0, 256)),
    ("render cursor", "POST", "/v1/worlds/{w}/render", {**CAMERA, "cursor": [X, 3]}, real(-1e6, 1e6)),
    ("render quality", "POST", "/v1/worlds/{w}/render", {**CAMERA, "quality": X}, NONE),
    ("pick x", "POST", "/v1/worlds/{w}/pick", {**CAMERA, "x": X, "y": 3}, real(-1e6, 1e6)),
    ("pick position", "POST", "/v1/worlds/{w}/pick", {**CAMERA, "position": [1, 2, X], "x": 3, "y": 3},
     real(-1e6, 1e6)),
]

# (name, path with X where the value goes, the values accepted)
QUERIES = [
    ("field min", "/v1/worlds/{w}/field?min=X,0,0&max=16,16,16", integer(0, 15)),
    ("field max", "/v1/worlds/{w}/field?min=0,0,0&max=16,X,16", integer(1, 16)),
    ("voxels min", "/v1/worlds/{w}/voxels?min=0,0,X&max=16,16,16", integer(0, 15)),
    # any version may yet be reached: a wait, answered 503 version_not_reached after max_wait_ms
    ("field min_version", "/v1/worlds/{w}/field?min_version=X", integer(0, 10 ** 400)),
    ("query min_version", "/v1/worlds/{w}/query?min_version=X", integer(0, 10 ** 400)),
    ("import chunk_size", "/v1/worlds/import?format=npy&chunk_size=X", NONE),
    ("import max_distance", "/v1/worlds/import?format=npy&max_distance=X", NONE),
    ("import model", "/v1/worlds/import?format=vox&model=X", integer(0, 0)),
]

# (name, WebSocket frame with X, the values accepted)
FRAMES = [
    ("ws box min", {"type": "edits", "edits": [{**BOX, "min": [X, 0, 0]}]}, INT32),
    ("ws sphere radius", {"type": "edits", "edits": [{**SPHERE, "radius": X}]}, real(0, 40)),
    ("ws voxel coordinate", {"type": "edits", "edits": [{**VOXELS, "voxels": [[1, X, 3, 9]]}]},
     integer(0, 15)),
    ("ws subscribe min", {"type": "subscribe", "min": [X, 0, 0], "max": [16, 16, 16]}, integer(0, 15)),
    ("ws subscribe max", {"type": "subscribe", "min": [0, 0, 0], "max": [16, 16, X]}, integer(1, 16)),
    ("ws camera position", {"type": "camera", **CAMERA, "position": [X, 30, 40]}, real(-1e6, 1e6)),
    ("ws camera width", {"type": "camera", **CAMERA, "width": X}, NONE),
    ("ws camera max_fps", {"type": "camera", **CAMERA, "max_fps": X}, real(0.01, 60)),
]


def json_text(value: Any) -> str:
    if value is NEST:
        return "[" * 5000 + "]" * 5000
    if value is LONG:
        return "[" + ",".join(["0"] * 2000) + "]"
    if isinstance(value, float) and math.isnan(value):
        return "NaN"
    if isinstance(value, float) and math.isinf(value):
        return "Infinity" if value > 0 else "-Infinity"
    return str(value)  # 10^400 goes as its 401 digits


def msgpack_bytes(value: Any) -> bytes | None:
    """The value in msgpack, or None where msgpack cannot carry it (integers of 2^64 and more)."""
    if value is NEST:
        return b"\x91" * 5000 + b"\xc0"
    if value is LONG:
        return msgpack.packb([0] * 2000)
    if isinstance(value, int) and not -2 ** 63 <= value < 2 ** 64:
        return None
    return msgpack.packb(value)


def as_json(body: Any, value: Any) -> bytes:
    return json.dumps(body).replace(json.dumps(X), json_text(value)).encode()


def as_msgpack(body: Any, value: Any) -> bytes | None:
    packed = msgpack_bytes(value)
    return None if packed is None else wire.encode(body).replace(msgpack.packb(X), packed)


def refused(valid: Callable[[Any], bool]) -> list[Any]:
    return [v for v in EXTREMES if v is NEST or v is LONG or not valid(v)]


def label(value: Any) -> Any:
    return LABELS.get(id(value), value)


@pytest.fixture(scope="module")
def target(tmp_path_factory):
    from hostile_server import HostileServer

    server = HostileServer(tmp_path_factory.mktemp("extremes") / "data").wait_ready()
    world = server.new_world()
    r = server.http.post(f"/v1/worlds/{world}/edits", json={"edits": [
        {"op": "box", "min": [2, 2, 2], "max": [6, 7, 8], "colour": 77}, SPHERE]})
    assert r.status_code == 200
    server.http.get(f"/v1/worlds/{world}/field?min_version=1")
    yield server, world
    server.stop()


def test_every_body_field_refuses_its_extremes(target):
    server, world = target
    before = server.state(world)
    answers = []
    for name, method, path, body, valid in BODIES:
        for value in refused(valid):
            for kind, encoded in (("json", as_json(body, value)), ("msgpack", as_msgpack(body, value))):
                if encoded is None:
                    continue
                r = server.http.request(method, path.format(w=world), content=encoded,
                                        headers={"content-type": f"application/{kind}"})
                status, code = error_of(r)
                answers.append((name, kind, label(value), status, code))
    wrong = [a[:4] for a in answers if not 400 <= a[3] < 500 or "not an error" in a[4]]
    assert not wrong, wrong
    assert len(answers) > 250
    assert server.state(world) == before


TEXT = "x" * 3000  # a string that a message echoing it whole would carry whole

# (name, method, path, body or raw bytes, extra headers): every place a client's string is named back
STRINGS: list[tuple[str, str, str, Any, dict[str, str]]] = [
    ("create metric", "POST", "/v1/worlds", {"size": [16, 16, 16], "metric": TEXT}, {}),
    ("create borders", "POST", "/v1/worlds", {"size": [16, 16, 16], "borders": TEXT}, {}),
    ("create storage", "POST", "/v1/worlds", {"size": [16, 16, 16], "storage": TEXT}, {}),
    ("create algorithm", "POST", "/v1/worlds", {"size": [16, 16, 16], "algorithm": TEXT}, {}),
    ("create chunk_size", "POST", "/v1/worlds", {"size": [16, 16, 16], "chunk_size": TEXT}, {}),
    ("create generate kind", "POST", "/v1/worlds",
     {"size": [16, 16, 16], "storage": "sparse", "generate": {"kind": TEXT}}, {}),
    ("patch algorithm", "PATCH", "/v1/worlds/{w}", {"algorithm": TEXT}, {}),
    ("patch borders", "PATCH", "/v1/worlds/{w}", {"borders": TEXT}, {}),
    ("edits op", "POST", "/v1/worlds/{w}/edits", {"edits": [{**BOX, "op": TEXT}]}, {}),
    ("edits content type", "POST", "/v1/worlds/{w}/edits", b"{}", {"content-type": TEXT}),
    ("query field name", "POST", "/v1/worlds/{w}/query", {"points": [[1, 1, 1]], TEXT: 1}, {}),
    ("render shadows", "POST", "/v1/worlds/{w}/render", {**CAMERA, "shadows": TEXT}, {}),
    ("field box", "GET", "/v1/worlds/{w}/field?min=" + TEXT + "&max=16,16,16", None, {}),
]


def test_long_strings_are_refused_without_being_echoed(target):
    """Each answer is a 4xx with the one error body, whose message (error_of: under 2,000
    characters) shows at most a prefix of the string; nothing changes."""
    server, world = target
    before = server.state(world)
    wrong = []
    for name, method, path, body, headers in STRINGS:
        content = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
        r = server.http.request(method, path.format(w=world), content=content,
                                headers={"content-type": "application/json", **headers})
        status, code = error_of(r)
        if not 400 <= status < 500 or "not an error" in code or TEXT[:100] in r.text:
            wrong.append((name, status, code))
    assert not wrong, wrong
    assert server.state(world) == before


def test_every_query_parameter_refuses_its_extremes(target):
    server, world = target
    before = server.state(world)
    wrong = []
    for name, path, valid in QUERIES:
        for value in refused(valid):
            text = json_text(value)
            url = path.format(w=world).replace("X", text)
            method = "GET" if "/field" in path or "/voxels" in path else "POST"
            body = json.dumps({"points": [[1, 1, 1]]}).encode() if "/query" in path else b"\x93NUMPY"
            r = server.http.request(method, url, content=body if method == "POST" else None)
            status, code = error_of(r)
            if not 400 <= status < 500 or "not an error" in code:
                wrong.append((name, label(value) if value in (NEST, LONG) else text[:20], status, code))
    assert not wrong, wrong
    assert server.state(world) == before


def test_blob_shapes_and_byte_counts_are_checked(target):
    server, world = target
    before = server.state(world)
    shapes = [[2 ** 32, 2 ** 32, 4], [2 ** 62, 4], [2 ** 63, 2], [0, 4], [-1, 4], [1, 2, 3, 4, 5, 6, 7, 8, 9]]
    sent = 0
    for shape in shapes:
        for dtype, data in (("uint16", b""), ("uint16", b"\x00" * 8), ("int64", b"\x01" * 32)):
            blob = {"dtype": dtype, "shape": shape, "data": data}
            for path, body in ((f"/v1/worlds/{world}/edits", {"edits": [{"op": "voxels", "voxels": blob}]}),
                               (f"/v1/worlds/{world}/query", {"points": {**blob, "dtype": "float32"}})):
                r = server.http.post(path, content=wire.encode(body), headers={"content-type": "application/msgpack"})
                status, code = error_of(r)
                assert 400 <= status < 500 and "not an error" not in code, (shape, dtype, path, r.text)
                sent += 1
    with connect(server.ws_url + f"/v1/worlds/{world}/stream", max_size=None) as ws:
        for shape in shapes:
            ws.send(wire.encode({"type": "edits", "id": 1, "edits": [
                {"op": "voxels", "voxels": {"dtype": "uint16", "shape": shape, "data": b""}}]}))
            answer = wire.decode(ws.recv(timeout=10))
            assert answer["type"] == "error" and answer["error"]["code"] in ("invalid_input", "invalid_edit"), answer
    assert sent == 36
    assert server.state(world) == before


def test_every_websocket_frame_field_refuses_its_extremes(target):
    server, world = target
    before = server.state(world)
    wrong, sent = [], 0
    with connect(server.ws_url + f"/v1/worlds/{world}/stream", max_size=None) as ws:
        for name, frame, valid in FRAMES:
            for value in refused(valid):
                encoded = as_msgpack({**frame, "id": sent}, value)
                if encoded is None:
                    continue
                ws.send(encoded)
                answer = wire.decode(ws.recv(timeout=10))
                sent += 1
                if answer.get("type") != "error" or not answer["error"]["code"] in (
                        "invalid_input", "invalid_edit", "too_large") or len(answer["error"]["message"]) >= 2000:
                    wrong.append((name, label(value), str(answer)[:200]))
        ws.send(wire.encode({"type": "ping", "id": "last"}))
        assert wire.decode(ws.recv(timeout=10)) == {"type": "pong", "id": "last"}  # still open
    assert not wrong, wrong
    assert sent > 50
    assert server.state(world) == before


def test_a_world_poisoned_by_an_older_server_is_described_again(start_server, tmp_path):
    """A focus of 10^30 chunks that an older server accepted and wrote to the catalog: the world
    restores, with the same focus narrowed to the world, and every answer describing it encodes."""
    server = start_server()
    world = server.new_world(focus={"center": [0, 0, 0], "size": [1, 1, 1]})
    server.stop()
    meta_path = tmp_path / "data" / "worlds" / world / "world.json"
    meta = json.loads(meta_path.read_text())
    meta["config"]["focus"]["size"] = [10 ** 30, 1, 1]
    meta_path.write_text(json.dumps(meta))
    server = start_server()
    for accept in ("application/json", "application/msgpack"):
        r = server.http.get("/v1/worlds", headers={"accept": accept})
        assert r.status_code == 200, r.text
    described = server.http.get(f"/v1/worlds/{world}").json()
    assert described["focus"] == {"center": [1, 0, 0], "size": [4, 1, 1]}  # chunks -1..2: all of x


def snapshot_file(header: bytes, body: bytes = b"") -> bytes:
    return b"SDFSNAP1" + len(header).to_bytes(4, "little") + header + body


def npy_file(header: str) -> bytes:
    text = header.encode()
    text += b" " * ((64 - (10 + len(text) + 1) % 64) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text + b"\x00" * 64


HOSTILE_FILES = {
    "snapshot header nested 20,000 deep": snapshot_file(b"[" * 20_000 + b"]" * 20_000),
    "snapshot version 10^400": snapshot_file(json.dumps({
        "format": 1, "version": "X", "config": {"size": [16, 16, 16]}, "compression": "zlib", "dtype": "uint8",
        "order": "zyx", "body_bytes": 0, "body_crc32": 0}).replace('"X"', "1e400").encode()),
    "snapshot sides of 2^62": snapshot_file(json.dumps({
        "format": 1, "version": 1, "config": {"size": [2 ** 62, 2 ** 62, 16]}, "compression": "zlib",
        "dtype": "uint8", "order": "zyx", "body_bytes": 0, "body_crc32": 0}).encode()),
    "npy shape of 2^40 a side": npy_file("{'descr': '|u1', 'fortran_order': False, "
                                         "'shape': (1099511627776, 1099511627776, 1099511627776), }"),
    "npy negative side": npy_file("{'descr': '|u1', 'fortran_order': False, 'shape': (-1, 4, 4), }"),
    "npy expression in its header": npy_file("{'descr': '|u1', 'fortran_order': False, 'shape': (2**40,), }"),
    "vox chunk of -1 bytes": b"VOX \x96\x00\x00\x00MAIN\x00\x00\x00\x00\xff\xff\xff\xff",
    "vox huge model": b"VOX \x96\x00\x00\x00MAIN\x00\x00\x00\x00\x18\x00\x00\x00SIZE\x0c\x00\x00\x00\x00\x00\x00\x00"
                      + (2 ** 31 - 1).to_bytes(4, "little") * 3,
}


def test_hostile_import_files(target):
    server, world = target
    before = server.state(world)
    wrong = []
    for name, data in HOSTILE_FILES.items():
        status, code = error_of(server.http.post("/v1/worlds/import", content=data))
        if not 400 <= status < 500 or "not an error" in code:
            wrong.append((name, status, code))
    assert not wrong, wrong
    assert server.state(world) == before
