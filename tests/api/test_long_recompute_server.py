"""A long recompute through a real server: while brute force recomputes a world in pieces, /readyz
lists it under `recomputing`, another world's edits and reads are answered, and the slow world's
read at its version comes once the recompute ends (issue 31)."""

from __future__ import annotations

import time

import httpx

from server_process import ServerProcess

SLOW = {"size": [64, 64, 64], "chunk_size": 16, "max_distance": 16, "algorithm": "brute"}
QUICK = {"size": [16, 16, 16], "chunk_size": 8, "max_distance": 8}


def test_a_world_recomputing_in_pieces_is_listed_and_others_are_served(tmp_path):
    server = ServerProcess(tmp_path / "data", "--no-warm-up", "--workers", "1", "--step-budget-ms", "4")
    server.wait_ready()
    try:
        with httpx.Client(base_url=server.url, timeout=60) as http:
            slow = http.post("/v1/worlds", json=SLOW).json()["id"]
            quick = http.post("/v1/worlds", json=QUICK).json()["id"]
            r = http.post(f"/v1/worlds/{quick}/edits", json={"edits": [
                {"op": "sphere", "center": [8.0, 8.0, 8.0], "radius": 3.0, "colour": 3}]})
            http.get(f"/v1/worlds/{quick}/field", params={"min_version": r.json()["version"]})  # kernels built
            r = http.post(f"/v1/worlds/{slow}/edits", json={"edits": [
                {"op": "sphere", "center": [32.0, 32.0, 32.0], "radius": 6.0, "colour": 9},
                {"op": "box", "min": [0, 0, 0], "max": [64, 2, 64], "colour": 4}]})
            assert r.status_code == 200
            seen, trips, deadline = None, [], time.monotonic() + 60
            while time.monotonic() < deadline:
                busy = http.get("/readyz").json()["busy"]
                listed = [e for b in busy for e in b.get("recomputing", [])]
                if listed:
                    seen = listed[0]
                elif seen is not None:
                    break  # it ended
                started = time.perf_counter()
                v = http.post(f"/v1/worlds/{quick}/edits", json={"edits": [
                    {"op": "voxels", "voxels": [[1, 2, 3, len(trips) % 200 + 1]]}]}).json()["version"]
                assert http.get(f"/v1/worlds/{quick}/field", params={"min_version": v}).status_code == 200
                trips.append(time.perf_counter() - started)
            assert seen is not None, "the brute-force recompute was never listed under recomputing"
            assert seen["world"] == slow and seen["algorithm"] == "brute" and seen["voxels"] == 64 ** 3
            assert len(trips) >= 3, trips
            r = http.get(f"/v1/worlds/{slow}/field", params={"min_version": 1},
                         headers={"accept": "application/octet-stream"})
            assert r.status_code == 200 and r.headers["x-sdf-version"] == "1"
    finally:
        server.stop()
