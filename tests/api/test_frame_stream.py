"""A WebSocket client's frame pipeline (``FrameStream``) with a stand-in engine and encoder: the
engine renders the next frame while this process encodes the last, frames go out in order, and an
engine error comes after the frames before it."""

from __future__ import annotations

import asyncio
import threading
import time

import numpy as np

from sdfserver.api import render_routes
from sdfserver.api.render_routes import FrameStream
from sdfserver.engine.messages import Array
from sdfserver.errors import NotFound

STAGE_S = 0.04
VIEW = {"type": "camera", "position": [40, 30, 40], "target": [8, 0, 8], "width": 32, "height": 16,
        "max_fps": 240}


class Frame:
    def __init__(self, version: int):
        self.pixels = Array.of(np.zeros((16, 32, 4), np.uint8))
        self.field_version, self.device_ms, self.field_ms = version, 0.1, 0.0


class StandInEngine:
    """Renders take STAGE_S; after ``frames`` renders the world is gone (NotFound)."""

    def __init__(self, frames: int):
        self.frames, self.renders = frames, []  # (start, end) of each render

    async def render(self, world_id, view, unless, access):
        if len(self.renders) == self.frames:
            raise NotFound(f"world {world_id} not found")
        start = time.monotonic()
        await asyncio.sleep(STAGE_S)
        self.renders.append((start, time.monotonic()))
        return Frame(len(self.renders))


def test_the_next_frame_renders_while_the_last_is_encoded_and_frames_go_out_in_order(monkeypatch):
    encodes: list[tuple[float, float]] = []
    lock = threading.Lock()

    def slow_encode(pixels, fmt, quality):
        start = time.monotonic()
        time.sleep(STAGE_S)
        with lock:
            encodes.append((start, time.monotonic()))
        return b"frame"

    monkeypatch.setattr(render_routes, "encode_frame", slow_encode)
    engine = StandInEngine(frames=8)
    sent: list[dict] = []

    async def run() -> None:
        done = asyncio.Event()

        async def send(message: dict) -> None:
            sent.append(message)
            if message["type"] == "error":
                done.set()

        stream = FrameStream(engine, "w", send)
        stream.set_view(VIEW)
        await asyncio.wait_for(done.wait(), 30)
        await stream.close()

    asyncio.run(run())
    frames = [m for m in sent if m["type"] == "frame"]
    assert sent[-1]["type"] == "error" and sent[-1]["error"]["code"] == "not_found"
    versions = [m["version"] for m in frames]
    assert versions == sorted(set(versions)) and len(versions) >= 6  # newest wins: one may be passed over
    overlapped = sum(any(r0 < e1 and e0 < r1 for e0, e1 in encodes) for r0, r1 in engine.renders)
    assert overlapped >= 4, (engine.renders, encodes)  # one after the other, none would
