"""Worlds survive a restart of a real server: voxels, versions, configuration and field."""

import numpy as np
import pytest

from durable_server import apply_reference, random_batch, read_voxels
from references import oracle_distance


@pytest.mark.parametrize("workers", ["1", "2"])
def test_worlds_and_fields_survive_restart_and_snapshots(start_server, tmp_path, workers):
    rng = np.random.default_rng()
    server = start_server("--snapshot-every-batches", "7", "--snapshot-min-interval-s", "0", "--workers", workers)
    sizes = {"a": (16, 16, 32), "b": (24, 16, 16)}
    ids, expected = {}, {}
    for name, size in sizes.items():
        r = server.http.post("/v1/worlds", json={"size": list(size), "chunk_size": 8, "max_distance": 12})
        assert r.status_code == 201, r.text
        ids[name] = r.json()["id"]
        expected[name] = np.zeros(size[::-1], np.uint8)
    for step in range(20):  # crosses several snapshots of each world
        for name, size in sizes.items():
            batch = random_batch(rng, size)
            r = server.http.post(f"/v1/worlds/{ids[name]}/edits", json={"edits": batch})
            assert r.status_code == 200 and r.json()["version"] == step + 1, r.text
            apply_reference(expected[name], batch)
    r = server.http.patch(f"/v1/worlds/{ids['b']}", json={"algorithm": "brute", "max_distance": 9})
    assert r.status_code == 200, r.text
    doomed = server.http.post("/v1/worlds", json={"size": [8, 8, 8], "chunk_size": 8}).json()["id"]
    assert server.http.delete(f"/v1/worlds/{doomed}").status_code == 204
    server.stop()
    snapshots = sorted(p.name for p in (tmp_path / "data" / "worlds" / ids["a"]).glob("snap-*"))
    assert snapshots, "no snapshot was written"

    server = start_server("--workers", workers)
    listed = {w["id"]: w for w in server.http.get("/v1/worlds").json()["worlds"]}
    assert set(listed) == set(ids.values())
    assert listed[ids["b"]]["algorithm"] == "brute" and listed[ids["b"]]["max_distance"] == 9
    for name in sizes:
        version, voxels = read_voxels(server.http, ids[name])
        assert version == 20
        np.testing.assert_array_equal(voxels, expected[name])
        cap = listed[ids[name]]["max_distance"]
        r = server.http.get(f"/v1/worlds/{ids[name]}/field", params={"min_version": 20},
                            headers={"accept": "application/octet-stream"})
        field = np.frombuffer(r.content, np.uint8).reshape(voxels.shape)
        np.testing.assert_array_equal(field, oracle_distance(expected[name], cap))
    r = server.http.post(f"/v1/worlds/{ids['a']}/edits", json={"edits": [{"op": "box", "min": [0, 0, 0],
                                                                           "max": [1, 1, 1], "colour": 5}]})
    assert r.json()["version"] == 21  # versions continue
