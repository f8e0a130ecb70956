"""A snapshot whose header names a format this server does not read — a number it does not
know, or a sparse world's format 2 over a dense body — is refused: an upload with 422 and
nothing created, a data directory's snapshot at restart with the world not restored and the
reason said, never an empty world."""

from __future__ import annotations

import json
import struct
import time

import pytest

from sdfserver.storage.snapshot import HEADER_AT, SNAPSHOT_MAGIC

from hostile_server import OCTET, error_of

BOX = {"op": "box", "min": [0, 0, 0], "max": [4, 4, 4], "colour": 9}  # 64 voxels


def with_header(snapshot: bytes, **changes) -> bytes:
    """``snapshot`` with its JSON header's fields changed, its body as it was."""
    (length,) = struct.unpack_from("<I", snapshot, len(SNAPSHOT_MAGIC))
    header = json.loads(snapshot[HEADER_AT:HEADER_AT + length])
    header.update(changes)
    encoded = json.dumps(header, sort_keys=True).encode()
    return SNAPSHOT_MAGIC + struct.pack("<I", len(encoded)) + encoded + snapshot[HEADER_AT + length:]


@pytest.mark.parametrize("changes", [{"format": 2}, {"format": 2, "dtype": "bricks"}, {"format": 3},
                                     {"format": 0}, {"format": "1"}, {"format": None}, {"format": True}],
                         ids=["2", "2-bricks", "3", "0", "string", "null", "true"])
def test_an_upload_of_an_unknown_format_is_422_and_creates_nothing(start_server, changes):
    server = start_server()
    world = server.new_world()
    assert server.http.post(f"/v1/worlds/{world}/edits", json={"edits": [BOX]}).status_code == 200
    exported = server.http.get(f"/v1/worlds/{world}/export", headers=OCTET).content
    assert server.http.post("/v1/worlds/import", content=exported).status_code == 201  # as exported: fine
    worlds = sorted(w["id"] for w in server.http.get("/v1/worlds").json()["worlds"])
    r = server.http.post("/v1/worlds/import", content=with_header(exported, **changes))
    assert error_of(r) == (422, "invalid_input"), r.text
    assert "format" in r.json()["error"]["message"]
    assert sorted(w["id"] for w in server.http.get("/v1/worlds").json()["worlds"]) == worlds


@pytest.mark.parametrize("format_number", [2, 3])
def test_a_stored_snapshot_of_an_unknown_format_is_refused_at_restart(start_server, tmp_path, format_number):
    server = start_server("--snapshot-every-batches", "1", "--snapshot-min-interval-s", "0")
    world, other = server.new_world(), server.new_world()
    assert server.http.post(f"/v1/worlds/{world}/edits", json={"edits": [BOX]}).status_code == 200
    directory = tmp_path / "data" / "worlds" / world
    deadline = time.monotonic() + 30
    while not list(directory.glob("snap-*.sdfsnap")) and time.monotonic() < deadline:
        time.sleep(0.05)  # written by a background thread after the batch
    server.stop()
    [snapshot] = directory.glob("snap-*.sdfsnap")
    snapshot.write_bytes(with_header(snapshot.read_bytes(), format=format_number))
    server = start_server()
    r = server.http.get(f"/v1/worlds/{world}")
    assert error_of(r) == (500, "storage_error"), r.text
    assert "unsupported format" in r.json()["error"]["message"] and snapshot.name in r.json()["error"]["message"]
    assert "NOT restored" in server.output() and world in server.output()
    assert [w["id"] for w in server.http.get("/v1/worlds").json()["worlds"]] == [other]
