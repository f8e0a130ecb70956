"""POST /render, POST /pick and frames on the WebSocket stream, against a real server."""

from __future__ import annotations

import asyncio
import io
import time

import httpx
import msgpack
import numpy as np
import pytest
import websockets
from PIL import Image

from sdfserver.render.scene import demo_scene

CAMERA = {"position": [40.5, 30.2, 50.7], "target": [16, 6, 16], "width": 64, "height": 48}


@pytest.fixture(scope="module")
def world(server):
    w = httpx.post(server + "/v1/worlds", json={"size": [32, 32, 32]}).json()
    assert httpx.post(server + f"/v1/worlds/{w['id']}/edits",
                      json={"edits": demo_scene((32, 32, 32))}).json()["version"] == 1
    return server, w["id"]


def render(base, world_id, **kwargs):
    return httpx.post(base + f"/v1/worlds/{world_id}/render", timeout=30, **kwargs)


def test_render_formats_agree(world):
    base, world_id = world
    raw = render(base, world_id, json={**CAMERA, "format": "rgba"})
    png = render(base, world_id, json=CAMERA, headers={"Accept": "image/png"})
    jpeg = render(base, world_id, json=CAMERA, params={"format": "jpeg"})
    assert raw.headers["content-type"] == "application/octet-stream"
    assert png.headers["content-type"] == "image/png" and jpeg.headers["content-type"] == "image/jpeg"
    for r in (raw, png, jpeg):
        assert r.status_code == 200 and int(r.headers["x-field-version"]) >= 1
    pixels = np.frombuffer(raw.content, np.uint8).reshape(48, 64, 4)
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(png.content))), pixels)
    decoded = np.asarray(Image.open(io.BytesIO(jpeg.content)).convert("RGB")).astype(int)
    assert np.abs(decoded - pixels[..., :3]).mean() < 12
    assert len(np.unique(pixels.reshape(-1, 4), axis=0)) > 3  # sky and several faces


@pytest.mark.parametrize("body, status", [
    ({**CAMERA, "width": 5000}, 413), ({**CAMERA, "position": [0, 0]}, 422),
    ({**CAMERA, "format": "gif"}, 422), ({**CAMERA, "bogus": 1}, 422),
])
def test_render_rejects_bad_cameras(world, body, status):
    base, world_id = world
    r = render(base, world_id, json=body)
    assert r.status_code == status and "message" in r.json()["error"]


def test_render_unknown_world_is_404(world):
    base, _ = world
    assert render(base, "no-such-world", json=CAMERA).status_code == 404


def test_pick_then_place_changes_the_frame(world):
    base, world_id = world
    before = render(base, world_id, json={**CAMERA, "format": "rgba"})
    hit = httpx.post(base + f"/v1/worlds/{world_id}/pick", json={**CAMERA, "x": 32.5, "y": 24.5}).json()
    assert hit["hit"] and [a + b for a, b in zip(hit["voxel"], hit["normal"])] == hit["place"]
    version = httpx.post(base + f"/v1/worlds/{world_id}/edits", json={"edits": [
        {"op": "sphere", "center": hit["place"], "radius": 2, "colour": 0x1F}]}).json()["version"]
    deadline = time.monotonic() + 10
    while True:
        after = render(base, world_id, json={**CAMERA, "format": "rgba"})
        if int(after.headers["x-field-version"]) >= version or time.monotonic() > deadline:
            break
    assert int(after.headers["x-field-version"]) >= version
    assert after.content != before.content


def test_stream_pushes_frames_of_new_versions(world):
    base, world_id = world
    asyncio.run(asyncio.wait_for(_stream(base, world_id), 60))


async def _stream(base, world_id):
    url = base.replace("http", "ws") + f"/v1/worlds/{world_id}/stream"
    async with websockets.connect(url, max_size=1 << 24) as ws:
        await ws.send(msgpack.packb({"type": "camera", **CAMERA, "max_fps": 1000}))
        error = msgpack.unpackb(await ws.recv())
        assert error["type"] == "error" and error["error"]["code"] == "invalid_input"
        await ws.send(msgpack.packb({"type": "camera", **CAMERA, "max_fps": 120, "format": "png"}))
        first = msgpack.unpackb(await ws.recv())
        assert first["type"] == "frame" and first["format"] == "png" and first["width"] == 64
        assert Image.open(io.BytesIO(first["data"])).size == (64, 48)
        await ws.send(msgpack.packb({"type": "edits", "id": 7, "edits": [
            {"op": "box", "min": [0, 0, 0], "max": [32, 32, 32], "colour": 0}]}))
        versions, acked = [], None
        while not versions or versions[-1] < (acked or 10**9):
            message = msgpack.unpackb(await ws.recv())
            if message["type"] == "ack":
                acked = message["version"]
            elif message["type"] == "frame":
                versions.append(message["version"])
                last = message
        assert versions == sorted(versions)
        sky = np.asarray(Image.open(io.BytesIO(last["data"])).convert("RGB"))
        assert len(np.unique(sky.reshape(-1, 3), axis=0)) == 1  # the world is empty now: all sky
