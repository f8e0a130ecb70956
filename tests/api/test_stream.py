"""The WebSocket stream: acknowledged edits, changed chunks only, and bounded memory for slow readers."""

from __future__ import annotations

import time

import numpy as np
import websockets.sync.client

from sdfserver import wire
from sdfserver.geometry import Box


def recv(ws, timeout: float = 20.0) -> dict:
    return wire.decode(ws.recv(timeout=timeout))


def paste(region_array: np.ndarray, region_lo, frame: dict) -> set[tuple[int, int, int]]:
    """Write a chunks frame into a local copy of the region; returns the chunks it carried."""
    seen = set()
    for chunk in frame["chunks"]:
        data = wire.unpack_array(chunk["data"])
        x, y, z = (o - l for o, l in zip(chunk["origin"], region_lo))
        cz, cy, cx = data.shape
        region_array[z:z + cz, y:y + cy, x:x + cx] = data
        seen.add(tuple(chunk["chunk"]))
    return seen


def test_edits_are_acked_and_only_changed_chunks_stream(server, ref):
    size, cs, cap = (32, 32, 32), 8, 4
    wid = server.create_world(size=list(size), chunk_size=cs, max_distance=cap)["id"]
    with websockets.sync.client.connect(server.ws_url + f"/v1/worlds/{wid}/stream") as ws:
        ws.send(wire.encode({"type": "subscribe", "id": "s", "min": [0, 0, 0], "max": [30, 32, 17]}))
        subscribed = recv(ws)
        assert subscribed == {"type": "subscribed", "id": "s", "min": [0, 0, 0], "max": [32, 32, 24],
                              "chunk_size": cs, "format": "distance", "dtype": "uint8", "content": "distance",
                              "metric": "manhattan", "signed": False}
        local = np.zeros((24, 32, 32), dtype=np.uint8)
        first = recv(ws)
        assert first["type"] == "chunks" and first["version"] == 0
        assert paste(local, (0, 0, 0), first) == {(x, y, z) for x in range(4) for y in range(4) for z in range(3)}
        assert (local == cap).all()

        rng = np.random.default_rng()
        expected = np.zeros(size[::-1], dtype=np.uint8)
        for i in range(4):
            corner = [int(v) for v in rng.integers(0, 28, 3)]
            batch = [{"op": "box", "min": corner, "max": [c + 3 for c in corner], "colour": 40 + i}]
            ws.send(wire.encode({"type": "edits", "id": i, "edits": batch}))
            ref.apply(expected, batch)
            ack, pending = recv(ws), None
            while ack["type"] == "chunks":  # chunks may overtake the ack (it waits for the log sync)
                pending = ack
                ack = recv(ws)
            assert ack == {"type": "ack", "id": i, "version": i + 1}
            frame = pending or recv(ws)
            assert frame["type"] == "chunks" and frame["version"] == i + 1
            seen = paste(local, (0, 0, 0), frame)
            # Exactly the chunks the edit's box, grown by the cap, touches (and the subscription holds).
            changed = Box(tuple(corner), tuple(c + 3 for c in corner)).grow(cap).snap(cs).intersect(
                Box((0, 0, 0), size)).chunk_range(cs)
            want = {(x, y, z) for x in range(changed.lo[0], changed.hi[0]) for y in range(changed.lo[1], changed.hi[1])
                    for z in range(changed.lo[2], min(changed.hi[2], 3))}
            assert seen == want
            np.testing.assert_array_equal(local, ref.distance(expected, cap)[:24])
        # The stream agrees with an HTTP read.
        field, _ = server.read(wid, "field", min="0,0,0", max="32,32,24", min_version=4)
        np.testing.assert_array_equal(local, field)
        ws.send(wire.encode({"type": "unsubscribe", "id": 9}))
        assert recv(ws) == {"type": "unsubscribed", "id": 9}
    server.http.delete(f"/v1/worlds/{wid}")


def test_slow_subscriber_does_not_grow_server_memory(server):
    size, cs = (64, 64, 64), 16
    wid = server.create_world(size=list(size), chunk_size=cs, max_distance=255)["id"]
    region_chunks = (64 // cs) ** 3
    # Nobody reads: the client stops taking frames off the socket after two, and the
    # server's sends soon block.
    with websockets.sync.client.connect(server.ws_url + f"/v1/worlds/{wid}/stream", max_size=None,
                                        max_queue=2, ping_interval=None) as ws:
        ws.send(wire.encode({"type": "subscribe", "min": [0, 0, 0], "max": list(size), "format": "packed"}))
        assert recv(ws)["type"] == "subscribed"
        # Warm up (kernels for this world's shape), then measure.
        server.edit(wid, [{"op": "box", "min": [0, 0, 0], "max": [1, 1, 1], "colour": 1}])
        rss_before = server.rss_bytes()
        merged_before = server.metric("sdfserver_stream_merged_chunks_total")
        rng = np.random.default_rng()
        batches = 200
        start = time.monotonic()
        for i in range(batches):
            # Each batch rewrites the whole field (cap 255): 512 KiB of updates per batch.
            center = [int(v) for v in rng.integers(0, 64, 3)]
            server.edit(wid, [{"op": "sphere", "center": center, "radius": 2.5, "colour": 1 + i % 255}])
        elapsed = time.monotonic() - start
        unbounded = batches * 2 * 64 ** 3
        grown = server.rss_bytes() - rss_before
        pending = server.metric("sdfserver_stream_pending_chunks")
        assert pending <= region_chunks, "a mailbox holds at most one copy of each subscribed chunk"
        assert server.metric("sdfserver_stream_pending_bytes") <= region_chunks * 2 * cs ** 3
        assert server.metric("sdfserver_stream_merged_chunks_total") - merged_before > 0, \
            "a reader this slow must have had updates merged"
        assert grown < unbounded / 4, f"RSS grew {grown / 2**20:.1f} MiB in {elapsed:.1f} s"

        # Reading now catches up to the newest state: newest data per chunk won.
        expected, _ = server.read(wid, "field", format="packed", min_version=batches + 1)
        local = np.zeros(size[::-1], dtype=np.uint16)
        version = 0
        deadline = time.monotonic() + 60
        while version < batches + 1 and time.monotonic() < deadline:
            frame = recv(ws)
            assert frame["type"] == "chunks"
            paste(local, (0, 0, 0), frame)
            version = frame["version"]
        assert version == batches + 1
        np.testing.assert_array_equal(local, expected)
    server.http.delete(f"/v1/worlds/{wid}")
    # Closing the socket unsubscribed it.
    deadline = time.monotonic() + 10
    while server.metric("sdfserver_stream_subscribers") and time.monotonic() < deadline:
        time.sleep(0.05)
    assert server.metric("sdfserver_stream_subscribers") == 0
    assert server.metric("sdfserver_websocket_clients") == 0
