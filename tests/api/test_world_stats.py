"""GET /v1/worlds/{id} and /metrics show what recomputes did: passes per algorithm, the world's
device memory and the exact transform's achieved bandwidth."""

from __future__ import annotations

import re

from sdfserver.world import World, WorldConfig


def described_after_edit(server, wid: str, edits: list) -> dict:
    version = server.edit(wid, edits, as_json=True)
    server.read(wid, "field", min_version=version)  # waits for the field
    return server.http.get(f"/v1/worlds/{wid}").json()


def labelled(server, name: str, algorithm: str) -> float:
    text = server.http.get("/metrics").text
    found = re.search(rf'^{name}{{algorithm="{algorithm}"}} (\S+)$', text, re.M)
    assert found, f"{name}{{algorithm={algorithm!r}}} not in /metrics"
    return float(found.group(1))


def test_fim_iterations_memory_and_exact_bandwidth(server):
    size = [32, 24, 16]
    world = server.create_world(size=size, chunk_size=8, max_distance=20, algorithm="fim")
    wid = world["id"]
    assert world["last_recompute"] is None
    assert world["device_bytes"] == sum(World.buffer_bytes(WorldConfig(tuple(size), 8, 20, "fim")))
    body = described_after_edit(server, wid, [{"op": "box", "min": [3, 4, 5], "max": [6, 7, 8], "colour": 9}])
    fim = body["last_recompute"]["algorithms"]["fim"]
    assert fim["iterations"] > 0 and fim["regions"] >= 1 and fim["device_ms"] > 0
    assert body["last_recompute"]["bandwidth_gbps"] is None  # exact did not run
    assert labelled(server, "sdfserver_recompute_last_iterations", "fim") > 0
    assert labelled(server, "sdfserver_recompute_iterations_total", "fim") >= fim["iterations"]

    server.http.patch(f"/v1/worlds/{wid}", json={"algorithm": "exact"})
    body = described_after_edit(server, wid, [{"op": "box", "min": [0, 0, 0], "max": [32, 24, 16],
                                               "colour": 0}])
    exact = body["last_recompute"]["algorithms"]["exact"]
    # Whole chunks within the cap of the edit: the whole world, 7 bytes a voxel.
    assert exact["bytes_moved"] == 7 * 32 * 24 * 16
    assert exact["bandwidth_gbps"] == body["last_recompute"]["bandwidth_gbps"] > 0
    assert labelled(server, "sdfserver_recompute_bandwidth_bytes_per_second", "exact") > 0
    assert labelled(server, "sdfserver_recompute_bytes_total", "exact") >= exact["bytes_moved"]
    assert server.metric("sdfserver_device_bytes") >= body["device_bytes"]
    server.http.delete(f"/v1/worlds/{wid}")


def test_focus_reports_both_algorithms(server):
    world = server.create_world(size=[32, 32, 32], chunk_size=8, max_distance=255, algorithm="exact",
                                lod_algorithm="conservative", focus={"center": [2, 2, 2], "size": [1, 1, 1]})
    body = described_after_edit(server, world["id"], [{"op": "sphere", "center": [9, 9, 9], "radius": 3.5,
                                                       "colour": 200}])
    assert body["lod_algorithm"] == "conservative"
    assert set(body["last_recompute"]["algorithms"]) == {"exact", "conservative"}
    server.http.delete(f"/v1/worlds/{world['id']}")
