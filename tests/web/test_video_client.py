"""The Python client receives the video stream: ``Stream.set_camera(format="h264")`` and
``sdfclient.video.FrameDecoder`` give the raw frames' pictures back, a missed chunk waits for a
keyframe, and ``request_keyframe`` brings one."""

from __future__ import annotations

import asyncio

import httpx
import numpy as np
import pytest

from sdfclient import Stream
from sdfclient.video import FrameDecoder, luma_psnr, psnr
from sdfserver.render.scene import demo_scene

CAMERA = {"position": [40.5, 30.2, 50.7], "target": [16, 6, 16], "width": 96, "height": 64}


@pytest.fixture(scope="module")
def world(server):
    w = httpx.post(server + "/v1/worlds", json={"size": [32, 32, 32]}).json()
    httpx.post(server + f"/v1/worlds/{w['id']}/edits", json={"edits": demo_scene((32, 32, 32))}).raise_for_status()
    return server, w["id"]


def raw_frame(base: str, world_id: str, version: int) -> np.ndarray:
    r = httpx.post(base + f"/v1/worlds/{world_id}/render", json={**CAMERA, "format": "rgba"}, timeout=60)
    assert int(r.headers["x-field-version"]) == version
    return np.frombuffer(r.content, np.uint8).reshape(CAMERA["height"], CAMERA["width"], 4)


def test_the_client_decodes_video_and_recovers_a_missed_chunk_with_a_keyframe(world):
    asyncio.run(asyncio.wait_for(_receive(*world), 120))


async def _next_frame(stream: Stream, decoder: FrameDecoder | None):
    """The next frame and, given a decoder, its picture."""
    async for message in stream:
        picture = None if decoder is None else decoder.feed(message.raw)
        if message.type == "frame":
            return message.raw, picture
    raise AssertionError("the stream ended")


async def _receive(base: str, world_id: str) -> None:
    decoder = FrameDecoder()
    async with Stream.connect(base, world_id) as stream:
        await stream.set_camera(CAMERA, format="h264", crf=18, keyframe_s=60)
        message, picture = await _next_frame(stream, decoder)
        assert decoder.video["codec"].startswith("avc1.") and message["key"]
        reference = raw_frame(base, world_id, message["version"])
        assert luma_psnr(picture, reference) >= 38 and psnr(picture, reference) >= 25

        # A chunk that never reached the decoder: what follows waits for a keyframe.
        version = await stream.edit([{"op": "sphere", "center": [12, 8, 12], "radius": 2.5, "colour": 0x1F}])
        missed, _ = await _next_frame(stream, None)  # read, not given to the decoder
        assert not missed["key"]
        version = await stream.edit([{"op": "sphere", "center": [18, 8, 12], "radius": 2.5, "colour": 0xE0}])
        message, picture = await _next_frame(stream, decoder)
        assert picture is None and decoder.needs_keyframe and not message["key"]
        await stream.request_keyframe()
        message, picture = await _next_frame(stream, decoder)
        assert message["key"] and not decoder.needs_keyframe and message["version"] == version
        assert luma_psnr(picture, raw_frame(base, world_id, version)) >= 38
