"""Crash test: a real server loaded with edits is killed with SIGKILL at random moments and
restarted, again and again over one data directory. After every restart: every acknowledged
batch is present, no batch is half-applied (the voxels equal a NumPy replay of whole batches in
version order) and versions continue without a gap. A batch in flight at the kill may be there
or not — but whole, and only as the next version."""

from __future__ import annotations

import os
import random
import threading
import time

import httpx
import numpy as np
import pytest

from durable_server import apply_reference, random_batch, read_voxels

TRIALS = int(os.environ.get("SDFSERVER_CRASH_TRIALS", "6"))
SIZE = (16, 16, 16)


class Writer(threading.Thread):
    """One client per world, one batch at a time, so an unacknowledged batch is known."""

    def __init__(self, url: str, world_id: str, seed: int, first_version: int):
        super().__init__(daemon=True)
        self.url, self.world_id = url, world_id
        self.rng = np.random.default_rng(seed)
        self.next_version = first_version
        self.acked: list[tuple[int, list]] = []
        self.in_flight: list | None = None
        self.errors: list[str] = []

    def run(self) -> None:
        with httpx.Client(base_url=self.url, timeout=10) as http:
            while True:
                batch = random_batch(self.rng, SIZE)
                self.in_flight = batch
                try:
                    r = http.post(f"/v1/worlds/{self.world_id}/edits", json={"edits": batch})
                except httpx.TransportError:
                    return  # the server died; in_flight may or may not be durable
                if r.status_code == 503 and "lost its server process" in r.text:
                    return  # a front's answer when the server died under it: the same
                if r.status_code != 200:
                    self.errors.append(r.text)
                    return
                version = r.json()["version"]
                if version != self.next_version:
                    self.errors.append(f"acknowledged version {version}, expected {self.next_version}")
                    return
                self.acked.append((version, batch))
                self.in_flight = None
                self.next_version += 1


@pytest.mark.parametrize("workers", ["1", "2"])  # acknowledgements through several API processes too
def test_sigkill_loses_no_acknowledged_batch(start_server, tmp_path, workers):
    seed = random.randrange(2 ** 32)
    rng = random.Random(seed)
    # snapshots and log trims happen under the kills too
    flags = ("--snapshot-every-batches", "40", "--snapshot-min-interval-s", "0", "--workers", workers)
    server = start_server(*flags)
    worlds = {}
    for _ in range(3):
        r = server.http.post("/v1/worlds", json={"size": list(SIZE), "chunk_size": 8, "max_distance": 8})
        assert r.status_code == 201, r.text
        worlds[r.json()["id"]] = (np.zeros(SIZE[::-1], np.uint8), 0)  # (expected voxels, version)
    acknowledged = in_flight_kept = lost = 0
    for trial in range(TRIALS):
        writers = [Writer(server.url, wid, rng.randrange(2 ** 32), version + 1)
                   for wid, (_, version) in worlds.items()]
        for w in writers:
            w.start()
        time.sleep(rng.uniform(0.2, 1.5))
        server.kill()
        for w in writers:
            w.join(30)
            assert not w.is_alive() and not w.errors, (seed, trial, w.errors)
        server = start_server(*flags, data_dir=tmp_path / "data")
        for w in writers:
            expected, version = worlds[w.world_id]
            for v, batch in w.acked:
                apply_reference(expected, batch)
            acknowledged += len(w.acked)
            version += len(w.acked)
            got_version, voxels = read_voxels(server.http, w.world_id)
            if got_version == version + 1 and w.in_flight is not None:  # the unacknowledged batch made it
                apply_reference(expected, w.in_flight)
                version += 1
                in_flight_kept += 1
            lost += max(0, version - got_version)
            assert got_version == version, (seed, trial, w.world_id, got_version, version)
            np.testing.assert_array_equal(voxels, expected, err_msg=f"seed {seed} trial {trial}")
            worlds[w.world_id] = (expected, version)
    print(f"\ncrash test: {TRIALS} trials (SIGKILL), {acknowledged} batches acknowledged, {lost} lost, "
          f"{in_flight_kept} unacknowledged in-flight batches found whole after restart (seed {seed})")
    assert lost == 0 and acknowledged > 0
