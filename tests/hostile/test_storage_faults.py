"""The data directory attacked under a running server, and restarts that must bring back what
was accepted: a deleted or replaced directory disables writes (503) and acknowledges nothing
more; a failed catalog write (read-only, full disk) answers storage_error and changes nothing;
a missing world.json is refused loudly; lowered limits do not make worlds unloadable."""

from __future__ import annotations

import json
import os
import shutil

from hostile_server import error_of

BOX = {"op": "box", "min": [0, 0, 0], "max": [4, 4, 4], "colour": 9}

# Catalog writes fail with the errno named in <data>/FAIL while that file exists.
FAILING_CATALOG = '''
import errno
from pathlib import Path
import sdfserver.storage.store as store

_real = store.write_atomic


def write_atomic(path, data):
    marker = Path(path).parents[2] / "FAIL"
    if Path(path).name == "world.json" and marker.exists():
        code = getattr(errno, marker.read_text().strip())
        raise OSError(code, errno.errorcode[code] + ": " + __import__("os").strerror(code))
    return _real(path, data)


store.write_atomic = write_atomic
'''


def post_box(server, world, colour):
    return server.http.post(f"/v1/worlds/{world}/edits", json={"edits": [{**BOX, "colour": colour}]})


def test_a_deleted_data_directory_disables_writes(start_server, tmp_path):
    server = start_server()
    world = server.new_world()
    assert post_box(server, world, 1).status_code == 200
    shutil.rmtree(tmp_path / "data")
    answers = [error_of(post_box(server, world, c)) for c in range(2, 52)]
    assert {a for a in answers} == {(503, "writes_disabled")}, answers  # none acknowledged
    status, code = error_of(server.http.get("/readyz"))
    assert (status, code) == (503, "writes_disabled")
    assert str(tmp_path / "data") in server.http.get("/readyz").json()["error"]["message"]
    assert error_of(server.http.post("/v1/worlds", json={"size": [16, 16, 16]})) == (503, "writes_disabled")
    assert error_of(server.http.patch(f"/v1/worlds/{world}", json={"max_distance": 9})) == (503, "writes_disabled")
    assert server.http.get(f"/v1/worlds/{world}").json()["max_distance"] == 16  # unchanged in memory
    assert server.http.get(f"/v1/worlds/{world}/voxels").status_code == 200  # reads go on


def test_a_replaced_data_directory_keeps_every_acknowledged_batch(start_server, tmp_path):
    server = start_server()
    world = server.new_world()
    acknowledged = [post_box(server, world, c).json()["version"] for c in range(1, 11)]
    os.rename(tmp_path / "data", tmp_path / "moved")
    (tmp_path / "data" / "worlds").mkdir(parents=True)
    answers = [post_box(server, world, c) for c in range(11, 31)]
    assert {error_of(r) for r in answers} == {(503, "writes_disabled")}
    server.stop()
    server = start_server(data_dir=tmp_path / "moved")
    # every acknowledged batch; the first refused one may be there too, whole (it reached the log)
    assert acknowledged[-1] == 10
    assert server.http.get(f"/v1/worlds/{world}").json()["version"] in (10, 11)


def test_a_failed_catalog_write_changes_nothing(start_server, tmp_path):
    server = start_server(hooks=FAILING_CATALOG)
    world = server.new_world()
    (tmp_path / "data" / "FAIL").write_text("EACCES")
    status, code = error_of(server.http.patch(f"/v1/worlds/{world}", json={"max_distance": 9}))
    assert (status, code) == (500, "storage_error")
    assert server.http.get(f"/v1/worlds/{world}").json()["max_distance"] == 16
    (tmp_path / "data" / "FAIL").write_text("ENOSPC")
    r = server.http.post("/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8})
    assert error_of(r) == (500, "storage_error") and "No space left" in r.json()["error"]["message"]
    assert sorted(p.name for p in (tmp_path / "data" / "worlds").iterdir()) == [world]  # no staging left
    assert post_box(server, world, 3).status_code == 200  # the logs are fine: edits go on
    (tmp_path / "data" / "FAIL").unlink()
    assert server.http.patch(f"/v1/worlds/{world}", json={"max_distance": 9}).status_code == 200
    server.stop()
    server = start_server()
    described = server.http.get(f"/v1/worlds/{world}").json()
    assert (described["max_distance"], described["version"]) == (9, 1)


def test_recovery_replays_what_was_accepted_whatever_the_limits(start_server):
    server = start_server()
    world = server.new_world()
    sphere = {"op": "sphere", "center": [8, 8, 8], "radius": 12, "colour": 5}
    assert server.http.post(f"/v1/worlds/{world}/edits", json={"edits": [sphere, BOX, BOX]}).status_code == 200
    voxels = server.state(world)[1]
    server.stop()
    server = start_server("--max-brush-radius-vox", "8", "--max-ops-per-batch", "1")
    assert server.http.get(f"/v1/worlds/{world}").json()["version"] == 1
    assert server.state(world)[1] == voxels
    r = server.http.post(f"/v1/worlds/{world}/edits", json={"edits": [sphere]})
    assert error_of(r) == (422, "invalid_edit")  # today's limits guard what comes in


def test_a_missing_catalog_entry_is_refused_loudly(start_server, tmp_path):
    server = start_server()
    world, other = server.new_world(), server.new_world()
    assert post_box(server, world, 4).status_code == 200
    server.stop()
    (tmp_path / "data" / "worlds" / world / "world.json").unlink()
    server = start_server()
    r = server.http.get(f"/v1/worlds/{world}")
    assert error_of(r) == (500, "storage_error")
    assert "world.json" in r.json()["error"]["message"]
    assert "NOT restored" in server.output() and world in server.output()
    assert [w["id"] for w in server.http.get("/v1/worlds").json()["worlds"]] == [other]
    assert list((tmp_path / "data" / "worlds" / world).glob("wal-*.log"))  # left for an operator
    assert json.loads(server.http.get("/readyz").text)["status"] == "ready"
