"""A WebSocket client's video frames (``FrameStream`` with ``format: "h264"``) from a stand-in
engine whose pictures are known: the stream decodes back to them, keyframes come where promised,
a resize starts a new stream, a slow reader loses frames and never gathers chunks, and the
encoder runs on a thread of its own."""

from __future__ import annotations

import asyncio
import threading
import time

import av
import numpy as np
import pytest

from sdfserver.api.render_routes import FrameStream
from sdfserver.engine.messages import Array
from sdfserver.errors import InvalidInput
from sdfserver.render import video

# Luma PSNR is how video is compared; RGB PSNR also counts 4:2:0's halved chroma resolution.
MIN_LUMA_PSNR_DB, MIN_RGB_PSNR_DB = 38.0, 28.0
VIEW = {"type": "camera", "position": [40, 30, 40], "target": [8, 0, 8], "width": 160, "height": 96,
        "max_fps": 60, "format": "h264"}


def picture(version: int, width: int, height: int) -> np.ndarray:
    """Smooth shading and a box that moves with the version: something like a rendered frame."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    rgba = np.empty((height, width, 4), np.uint8)
    rgba[..., 0] = 120 + 60 * np.sin(x / 17 + version / 5)
    rgba[..., 1] = 150 + 50 * np.cos(y / 11)
    rgba[..., 2] = 200 - 0.3 * y
    rgba[..., 3] = 255
    left = (version * 3) % (width - 24)
    rgba[height // 3:height // 3 + 20, left:left + 24, :3] = (200, 60, 40)
    return rgba


class Frame:
    def __init__(self, pixels: np.ndarray, version: int):
        self.pixels = Array.of(pixels)
        self.field_version, self.device_ms, self.field_ms = version, 0.5, 0.0


class ChangingEngine:
    """Every render shows a new field version: frames flow at max_fps, as under an edit a frame."""

    def __init__(self, render_s: float = 0.002):
        self.render_s = render_s
        self.pictures: dict[int, np.ndarray] = {}

    async def render(self, world_id, view, unless, access):
        await asyncio.sleep(self.render_s)
        version = len(self.pictures) + 1
        self.pictures[version] = picture(version, view["width"], view["height"])
        return Frame(self.pictures[version], version)


async def stream_for(engine, seconds: float, *views: dict, send=None, between=None) -> list[dict]:
    sent: list[dict] = []

    async def keep(message: dict) -> None:
        sent.append(message)

    stream = FrameStream(engine, "w", send or keep)
    try:
        for view in views:
            stream.set_view(view)
            await asyncio.sleep(seconds)
            if between is not None:
                await between(stream)
    finally:
        await stream.close()
    return sent


def psnr(decoded: np.ndarray, reference: np.ndarray, weights=None) -> float:
    """RGB PSNR in dB, or with ``weights`` (BT.709's) the PSNR of the luma."""
    a, b = decoded[..., :3].astype(np.float64), reference[..., :3].astype(np.float64)
    if weights is not None:
        a, b = a @ weights, b @ weights
    return 10 * np.log10(255 ** 2 / np.mean((a - b) ** 2))


def luma_psnr(decoded: np.ndarray, reference: np.ndarray) -> float:
    return psnr(decoded, reference, np.array([0.2126, 0.7152, 0.0722]))


class Decoder:
    """FFmpeg's own H.264 decoder, restarted at every ``video`` message; a chunk that does not
    decode to exactly one picture at once fails the test."""

    def __init__(self) -> None:
        self.context = None

    def feed(self, message: dict) -> np.ndarray | None:
        if message["type"] == "video":
            self.context = av.CodecContext.create("h264", "r")
            return None
        assert self.context is not None, "a chunk before the stream's video message"
        pictures = self.context.decode(av.Packet(message["data"]))
        assert len(pictures) == 1, f"chunk {message['seq']} gave {len(pictures)} pictures"
        return pictures[0].to_ndarray(format="rgb24")


def decode_all(messages: list[dict], engine: ChangingEngine) -> list[tuple[dict, np.ndarray]]:
    """Every frame decoded, each checked against the picture of its version."""
    decoder, out = Decoder(), []
    for message in messages:
        decoded = decoder.feed(message)
        if message["type"] != "frame":
            continue
        reference = engine.pictures[message["version"]][:message["height"], :message["width"]]
        assert decoded.shape == reference[..., :3].shape
        assert luma_psnr(decoded, reference) >= MIN_LUMA_PSNR_DB, (message["seq"], luma_psnr(decoded, reference))
        assert psnr(decoded, reference) >= MIN_RGB_PSNR_DB, (message["seq"], psnr(decoded, reference))
        out.append((message, decoded))
    return out


def test_a_video_stream_decodes_to_the_rendered_pictures_with_keyframes_on_schedule():
    engine = ChangingEngine()
    keyframe_s = 0.25
    sent = asyncio.run(stream_for(engine, 1.3, {**VIEW, "keyframe_s": keyframe_s}))
    first = sent[0]
    assert first["type"] == "video" and first["format"] == "h264" and first["bitstream"] == "annexb"
    assert first["encoder"] in video.ENCODERS["h264"] and first["hardware"] == (first["encoder"] == "h264_nvenc")
    assert first["codec"].startswith("avc1.") and len(first["codec"]) == 11
    assert (first["width"], first["height"], first["crf"], first["bitrate"]) == (160, 96, video.DEFAULT_CRF["h264"], None)
    frames = [m for m, _ in decode_all(sent, engine)]
    assert len(frames) >= 40 and all(m["codec"] == first["codec"] for m in frames)
    assert [m["seq"] for m in frames] == list(range(frames[0]["seq"], frames[0]["seq"] + len(frames)))
    assert frames[0]["key"] and frames[0]["timestamp"] == 0
    timestamps = [m["timestamp"] for m in frames]
    assert timestamps == sorted(set(timestamps))
    keys = [m["timestamp"] / 1e6 for m in frames if m["key"]]
    gaps = np.diff(keys)
    period = 1 / VIEW["max_fps"]
    # A keyframe is the first frame at least keyframe_s after the last one, and no others come.
    assert len(keys) >= 4 and np.all(gaps >= keyframe_s) and np.all(gaps <= keyframe_s + 3 * period), keys
    assert all(m["latency_ms"] >= m["encode_ms"] > 0 for m in frames)


def test_a_keyframe_comes_when_asked_for_and_otherwise_only_at_the_start():
    engine = ChangingEngine()
    asked_at: list[int] = []

    async def ask(stream: FrameStream) -> None:
        asked_at.append(stream.seq)
        stream.request_keyframe()
        await asyncio.sleep(0.3)

    sent = asyncio.run(stream_for(engine, 0.4, {**VIEW, "keyframe_s": 600}, between=ask))
    frames = [m for m, _ in decode_all(sent, engine)]
    keys = [m["seq"] for m in frames if m["key"]]
    assert keys[0] == frames[0]["seq"] and len(keys) == 2, keys
    # The frame being encoded when it was asked for may still be a delta; the next is the keyframe.
    assert asked_at[0] < keys[1] <= asked_at[0] + 2, (asked_at, keys)


def test_a_resize_starts_a_new_stream_with_a_keyframe():
    engine = ChangingEngine()
    sent = asyncio.run(stream_for(engine, 0.4, VIEW, {**VIEW, "width": 121, "height": 64}))
    starts = [i for i, m in enumerate(sent) if m["type"] == "video"]
    assert len(starts) == 2, [m["type"] for m in sent]
    second = sent[starts[1]]
    assert (second["width"], second["height"]) == (120, 64)  # 4:2:0: an odd width loses a column
    after = sent[starts[1] + 1]
    assert after["type"] == "frame" and after["key"] and after["timestamp"] == 0
    assert all((m["width"], m["height"]) == (120, 64) for m in sent[starts[1] + 1:] if m["type"] == "frame")
    assert len(decode_all(sent, engine)) == sum(m["type"] == "frame" for m in sent)  # one decoder throughout
    fresh = Decoder()  # a client that joins at the new stream decodes it too
    for message in sent[starts[1]:]:
        assert (fresh.feed(message) is None) == (message["type"] == "video")


def test_pictures_between_video_streams_release_the_encoder_and_video_resumes_with_a_new_stream():
    engine = ChangingEngine()
    released: list[bool] = []

    async def check(stream: FrameStream) -> None:
        released.append(stream.video._encoder is None)

    sent = asyncio.run(stream_for(engine, 0.3, VIEW, {**VIEW, "format": "png"}, VIEW, between=check))
    assert released == [False, True, False]
    kinds = [m["type"] if m["type"] == "video" else m["format"] for m in sent]
    first_png, last_png = kinds.index("png"), len(kinds) - 1 - kinds[::-1].index("png")
    assert kinds[0] == "video" and kinds[last_png + 1] == "video" and "video" not in kinds[first_png:last_png]
    resumed = sent[last_png + 2]
    assert resumed["key"] and resumed["timestamp"] == 0
    decode_all(sent[last_png + 1:], engine)


def test_a_slow_reader_loses_frames_not_chunks_and_nothing_gathers():
    engine = ChangingEngine(render_s=0.001)
    reading = asyncio.Event()
    sent: list[dict] = []
    backlog: list[int] = []  # chunks encoded and not yet sent, sampled while the reader stalls

    async def slow_send(message: dict) -> None:
        if len(sent) >= 3:
            await reading.wait()  # the reader stops taking frames off the socket
        sent.append(message)

    async def run() -> None:
        stream = FrameStream(engine, "w", slow_send)
        stream.set_view({**VIEW, "max_fps": 240, "keyframe_s": 600})
        for _ in range(40):
            await asyncio.sleep(0.02)
            backlog.append(stream.seq - sum(m["type"] == "frame" for m in sent))
        rendered_while_stalled = len(engine.pictures)
        reading.set()
        await asyncio.sleep(0.3)
        await stream.close()
        assert rendered_while_stalled > 100  # the renderer went on: the stall cost frames, not renders

    asyncio.run(run())
    # One chunk in the blocked send and one in the slot at most: no queue grows behind a slow reader.
    assert max(backlog) <= 2, backlog
    frames = [m for m, _ in decode_all(sent, engine)]
    assert [m["seq"] for m in frames] == list(range(1, len(frames) + 1))  # no chunk was dropped
    assert sum(m["key"] for m in frames) == 1  # so none had to be replaced by a keyframe
    versions = [m["version"] for m in frames]
    assert max(np.diff(versions)) > 50  # the frames rendered during the stall were passed over
    assert versions[-1] >= len(engine.pictures) - 5  # and the newest came once the reader was back


def test_video_is_encoded_on_its_own_thread_while_the_engine_renders(monkeypatch):
    threads: set[str] = set()
    encodes: list[tuple[float, float]] = []
    real_encode = video.VideoEncoder.encode

    def encode(self, rgba, timestamp_us, key):
        start = time.monotonic()
        threads.add(threading.current_thread().name)
        time.sleep(0.02)  # a slow encoder
        chunk = real_encode(self, rgba, timestamp_us, key)
        encodes.append((start, time.monotonic()))
        return chunk

    monkeypatch.setattr(video.VideoEncoder, "encode", encode)
    engine = ChangingEngine(render_s=0.02)
    renders: list[tuple[float, float]] = []
    plain_render = engine.render

    async def timed_render(*args):
        start = time.monotonic()
        frame = await plain_render(*args)
        renders.append((start, time.monotonic()))
        return frame

    engine.render = timed_render
    sent = asyncio.run(stream_for(engine, 0.5, {**VIEW, "max_fps": 240}))
    assert threads and all(name.startswith("sdfserver-video") for name in threads), threads
    assert threading.main_thread().name not in threads
    overlapped = sum(any(r0 < e1 and e0 < r1 for e0, e1 in encodes) for r0, r1 in renders)
    assert overlapped >= len(renders) // 2, (renders, encodes)
    decode_all(sent, engine)


@pytest.mark.parametrize("change, message", [
    ({"quality": 80}, "quality is for pictures"),
    ({"bitrate": 2_000_000, "crf": 20}, "bitrate or crf"),
    ({"bitrate": 10}, "bitrate must be"),
    ({"crf": 60}, "crf must be"),
    ({"keyframe_s": 0}, "keyframe_s must be"),
    ({"encoder": "libvpx-vp9"}, "encoder for h264"),
    ({"format": "vp9", "preset": "ultrafast"}, "preset is libx264's"),
    ({"format": "jpeg", "bitrate": 2_000_000}, "settings of the video formats"),
    ({"format": "gif"}, "format must be one of"),
])
def test_bad_video_settings_are_refused_and_the_view_is_kept(change, message):
    async def run() -> None:
        stream = FrameStream(ChangingEngine(), "w", None)
        with pytest.raises(InvalidInput, match=message):
            stream.set_view({**VIEW, **change})
        assert stream.view is None
        with pytest.raises(InvalidInput, match="a keyframe is asked of a video stream"):
            stream.request_keyframe()

    asyncio.run(run())
