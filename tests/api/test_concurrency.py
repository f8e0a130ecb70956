"""Many clients editing one world end in the state of applying their batches in version order."""

from __future__ import annotations

import threading

import httpx
import numpy as np

from sdfserver import wire

CLIENTS = 8
BATCHES = 10


def test_concurrent_clients_match_version_order_replay(server, ref):
    size, cap = (32, 32, 32), 7
    wid = server.create_world(size=list(size), chunk_size=8, max_distance=cap)["id"]
    seed = int(np.random.SeedSequence().entropy % 2**32)
    acked: list[tuple[int, list[dict]]] = []
    lock = threading.Lock()
    barrier = threading.Barrier(CLIENTS)
    failures: list[BaseException] = []

    def client(index: int) -> None:
        rng = np.random.default_rng([seed, index])
        try:
            with httpx.Client(base_url=server.url, timeout=30) as http:
                barrier.wait()
                for i in range(BATCHES):
                    # Overlapping edits from every client, so the order matters.
                    batch = ref.batch(rng, size) + [{"op": "box", "min": [8, 8, 8], "max": [20, 20, 20],
                                                     "colour": index * 16 + i + 1}]
                    if i % 2:
                        r = http.post(f"/v1/worlds/{wid}/edits", content=wire.encode({"edits": batch}),
                                      headers={"content-type": wire.CONTENT_TYPE, "accept": "application/json"})
                    else:
                        as_lists = [{**op, "voxels": op["voxels"].tolist()} if op["op"] == "voxels" else op
                                    for op in batch]
                        r = http.post(f"/v1/worlds/{wid}/edits", json={"edits": as_lists})
                    assert r.status_code == 200, r.text
                    with lock:
                        acked.append((r.json()["version"], batch))
        except BaseException as exc:  # reported below; a thread cannot fail the test itself
            failures.append(exc)

    threads = [threading.Thread(target=client, args=(i,)) for i in range(CLIENTS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not failures, failures
    versions = sorted(v for v, _ in acked)
    assert versions == list(range(1, CLIENTS * BATCHES + 1)), "versions must rise by one per batch"

    expected = np.zeros(size[::-1], dtype=np.uint8)
    for _, batch in sorted(acked, key=lambda item: item[0]):
        ref.apply(expected, batch)
    voxels, msg = server.read(wid, "voxels")
    assert msg["version"] == CLIENTS * BATCHES
    np.testing.assert_array_equal(voxels, expected, err_msg=f"seed {seed}")
    field, msg = server.read(wid, "field", min_version=CLIENTS * BATCHES)
    np.testing.assert_array_equal(field, ref.distance(expected, cap), err_msg=f"seed {seed}")
    # The engine merged concurrent batches into fewer steps than batches, each still versioned.
    described = server.http.get(f"/v1/worlds/{wid}").json()
    assert described["version"] == described["field_version"] == CLIENTS * BATCHES
    server.http.delete(f"/v1/worlds/{wid}")
