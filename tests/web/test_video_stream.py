"""H.264 frames on the WebSocket stream of a real server, decoded with FFmpeg (PyAV) and compared
with the raw RGBA frames that ``POST /render`` gives for the same view and field version."""

from __future__ import annotations

import asyncio

import av
import httpx
import msgpack
import numpy as np
import pytest
import websockets

from sdfserver.render.scene import demo_scene

CAMERA = {"position": [40.5, 30.2, 50.7], "target": [16, 6, 16], "width": 96, "height": 64}
MIN_LUMA_PSNR_DB = 38.0
LUMA = np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture(scope="module")
def world(server):
    w = httpx.post(server + "/v1/worlds", json={"size": [32, 32, 32]}).json()
    httpx.post(server + f"/v1/worlds/{w['id']}/edits", json={"edits": demo_scene((32, 32, 32))}).raise_for_status()
    return server, w["id"]


def raw_frame(base: str, world_id: str, camera: dict, version: int) -> np.ndarray:
    r = httpx.post(base + f"/v1/worlds/{world_id}/render", json={**camera, "format": "rgba"}, timeout=60)
    assert r.status_code == 200 and int(r.headers["x-field-version"]) == version, (r.headers, version)
    return np.frombuffer(r.content, np.uint8).reshape(camera["height"], camera["width"], 4)


def luma_psnr(decoded: np.ndarray, reference: np.ndarray) -> float:
    error = (decoded[..., :3].astype(float) - reference[..., :3].astype(float)) @ LUMA
    return 10 * np.log10(255 ** 2 / np.mean(error ** 2))


class Receiver:
    """Frames decoded strictly in order through one decoder; answers kept aside for ``ack``."""

    def __init__(self, ws):
        self.ws, self.decoder, self.video = ws, None, None
        self.pictures_due: list[dict] = []  # video and frame messages read while waiting for an answer
        self.acks: list[dict] = []

    async def _read(self) -> dict:
        message = msgpack.unpackb(await self.ws.recv())
        assert message["type"] != "error", message
        return message

    async def ack(self) -> dict:
        while not self.acks:
            message = await self._read()
            (self.acks if message["type"] == "ack" else self.pictures_due).append(message)
        return self.acks.pop(0)

    async def picture(self) -> tuple[dict, np.ndarray]:
        """The next frame, decoded."""
        while True:
            message = self.pictures_due.pop(0) if self.pictures_due else await self._read()
            if message["type"] == "ack":
                self.acks.append(message)
            elif message["type"] == "video":
                self.video, self.decoder = message, av.CodecContext.create("h264", "r")
            elif message["type"] == "frame":
                pictures = self.decoder.decode(av.Packet(message["data"]))
                assert len(pictures) == 1
                return message, pictures[0].to_ndarray(format="rgb24")


def test_h264_frames_match_the_raw_frames_through_edits_resizes_and_keyframe_requests(world):
    asyncio.run(asyncio.wait_for(_stream(*world), 120))


async def _stream(base: str, world_id: str) -> None:
    url = base.replace("http", "ws") + f"/v1/worlds/{world_id}/stream"
    async with websockets.connect(url, max_size=1 << 24) as ws:
        stream = Receiver(ws)
        await ws.send(msgpack.packb({"type": "camera", "id": 1, **CAMERA, "format": "h264", "crf": 18,
                                     "keyframe_s": 60}))
        message, picture = await stream.picture()
        assert stream.video["encoder"] in ("libx264", "h264_nvenc") and stream.video["codec"].startswith("avc1.")
        assert message["key"] and message["timestamp"] == 0 and message["latency_ms"] >= message["encode_ms"]
        assert message["view_id"] == 1
        reference = raw_frame(base, world_id, CAMERA, message["version"])
        assert luma_psnr(picture, reference) >= MIN_LUMA_PSNR_DB

        # Edits: the next frames are deltas of the first, and still the raw frames' pictures.
        for i in range(3):
            await ws.send(msgpack.packb({"type": "edits", "id": i, "edits": [
                {"op": "sphere", "center": [10 + 4 * i, 8, 12], "radius": 2.5, "colour": 0x1F}]}))
            acked = (await stream.ack())["version"]
            while True:
                message, picture = await stream.picture()
                if message["version"] >= acked:
                    break
            assert not message["key"]
            reference = raw_frame(base, world_id, CAMERA, message["version"])
            assert luma_psnr(picture, reference) >= MIN_LUMA_PSNR_DB, i

        # A keyframe when asked for, though nothing changed.
        await ws.send(msgpack.packb({"type": "keyframe"}))
        message, picture = await stream.picture()
        assert message["key"] and message["version"] == acked

        # A resize: a new stream (video message, keyframe, timestamps from 0) of the new size.
        resized = {**CAMERA, "width": 64, "height": 48}
        await ws.send(msgpack.packb({"type": "camera", "id": 2, **resized, "format": "h264", "crf": 18}))
        message, picture = await stream.picture()
        assert (stream.video["width"], stream.video["height"]) == (64, 48)
        assert message["key"] and message["timestamp"] == 0 and picture.shape == (48, 64, 3)
        assert message["view_id"] == 2
        assert luma_psnr(picture, raw_frame(base, world_id, resized, message["version"])) >= MIN_LUMA_PSNR_DB
