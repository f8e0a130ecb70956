"""Consecutive frames of one view as one video stream: H.264, VP9 or AV1 through PyAV (FFmpeg).

Every frame handed to ``VideoEncoder.encode`` comes back as one chunk at once: no B-frames and no
lookahead (x264's ``tune=zerolatency``, NVENC's ultra-low-latency tuning, VP9's realtime deadline
with no lag, SVT-AV1's low-delay prediction structure), so a chunk can leave as soon as its frame
is encoded. Keyframes come only when asked for (scene-cut detection is off), so that a client knows
where they are and a large intra frame never arrives unannounced.

Chunks are what WebCodecs' ``EncodedVideoChunk`` takes from a ``VideoDecoder`` configured with
``codec`` alone, without ``description``: H.264 as Annex B (start codes, with SPS and PPS in-band
before every keyframe), VP9 as its frames, AV1 as its temporal units. A decoder can start at any
keyframe. ``codec`` is the WebCodecs codec string: for H.264 read from the stream's SPS, for VP9
and AV1 the profile and the level that the picture size and frame rate need.

Colour: RGBA frames become 4:2:0 BT.709 limited range, and the stream says so in its colour
description (H.264's VUI), so that a browser and FFmpeg convert it back alike.

Per format the encoders are tried in order, hardware first: NVENC opens only on a GPU with an
encoder unit and its driver library; whether it opened is remembered for the process.

Rate: ``crf`` holds a quality, whatever the frame rate; ``bitrate`` is a rate at ``max_fps`` frames
a second, capped over half a second. Frames come only when the view or the field changed, and all
but VP9 give each frame a share of the rate as if frames came at ``max_fps`` (libx264 would follow
the timestamps only a frame late), so a stream whose frames come slower spends less, not more per
frame: a client that names a bitrate names the ``max_fps`` it expects to get.
"""

from __future__ import annotations

import asyncio
import math
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from fractions import Fraction
from typing import Any

import numpy as np

from sdfserver.errors import InvalidInput
from sdfserver.incoming import short

try:
    import av
    from av.video.reformatter import ColorRange, Colorspace
except ImportError:  # the video formats are then refused with a reason
    av = None

# Hardware first; the first one that opens serves the stream.
ENCODERS = {"h264": ("h264_nvenc", "libx264"), "vp9": ("libvpx-vp9",), "av1": ("av1_nvenc", "libsvtav1")}
HARDWARE = frozenset({"h264_nvenc", "av1_nvenc"})
VIDEO_FORMATS = tuple(ENCODERS)
# Constant-quality scale (x264's CRF, NVENC's CQ, VP9's and SVT-AV1's CRF): its range and default.
CRF_RANGE = {"h264": (0, 51), "vp9": (0, 63), "av1": (1, 63)}
DEFAULT_CRF = {"h264": 23, "vp9": 32, "av1": 35}
X264_PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast")
MIN_BITRATE, MAX_BITRATE = 100_000, 200_000_000
MIN_KEYFRAME_S, MAX_KEYFRAME_S, DEFAULT_KEYFRAME_S = 0.1, 600.0, 2.0
TIME_BASE = Fraction(1, 1_000_000)  # timestamps in microseconds, as WebCodecs counts them
# Keys of a camera message that configure the video rather than the picture.
VIDEO_KEYS = frozenset({"bitrate", "crf", "keyframe_s", "encoder", "preset"})
# An intra period longer than any stream lasts: keyframes are forced, never scheduled by the codec.
NO_AUTOMATIC_KEYFRAMES = 1 << 30


@dataclass(frozen=True)
class VideoRequest:
    """What a client asked for. ``bitrate`` (bit/s) or ``crf`` sets the rate control, never both."""

    format: str
    bitrate: int | None = None
    crf: int | None = None
    keyframe_s: float = DEFAULT_KEYFRAME_S
    encoder: str | None = None  # pinned by the client; else the first of ENCODERS that opens
    preset: str = "veryfast"  # libx264's

    def stream_key(self, width: int, height: int, fps: float) -> tuple:
        """What an encoder is opened for: a change of any of it starts a new stream."""
        return (self.format, self.bitrate, self.crf, self.encoder, self.preset, width, height, fps)


def parse_video_request(message: dict[str, Any], fmt: str) -> VideoRequest:
    """The video settings of a camera message whose ``format`` is a video format; InvalidInput
    names the first bad one."""
    if av is None:
        raise InvalidInput(f"format {short(fmt)} needs PyAV (pip install av), which this server lacks")
    if fmt not in ENCODERS:
        raise InvalidInput(f"video format must be one of {list(VIDEO_FORMATS)}, got {short(fmt)}")
    request = VideoRequest(fmt)
    if message.get("bitrate") is not None and message.get("crf") is not None:
        raise InvalidInput("give bitrate or crf, not both")
    if message.get("bitrate") is not None:
        request = replace(request, bitrate=_integer(message["bitrate"], "bitrate", MIN_BITRATE, MAX_BITRATE))
    elif message.get("crf") is not None:
        request = replace(request, crf=_integer(message["crf"], "crf", *CRF_RANGE[fmt]))
    else:
        request = replace(request, crf=DEFAULT_CRF[fmt])
    if message.get("keyframe_s") is not None:
        seconds = message["keyframe_s"]
        if (isinstance(seconds, bool) or not isinstance(seconds, (int, float))
                or not MIN_KEYFRAME_S <= seconds <= MAX_KEYFRAME_S):
            raise InvalidInput(f"keyframe_s must be a number of seconds {MIN_KEYFRAME_S:g}..{MAX_KEYFRAME_S:g}, "
                               f"got {seconds!r}")
        request = replace(request, keyframe_s=float(seconds))
    if message.get("encoder") is not None:
        if message["encoder"] not in available_encoders(fmt):
            raise InvalidInput(f"encoder for {fmt} must be one of {available_encoders(fmt)}, got {short(message['encoder'])}")
        request = replace(request, encoder=message["encoder"])
    if message.get("preset") is not None:
        if fmt != "h264" or message["preset"] not in X264_PRESETS:
            raise InvalidInput(f"preset is libx264's, one of {list(X264_PRESETS)} (h264 only), got {message['preset']!r}")
        request = replace(request, preset=message["preset"])
    return request


def available_encoders(fmt: str) -> list[str]:
    """The encoders for ``fmt`` that this FFmpeg build has (whether hardware ones open is another matter)."""
    found = []
    for name in ENCODERS.get(fmt, ()):
        try:
            av.codec.Codec(name, "w")
        except av.codec.codec.UnknownCodecError:
            continue
        found.append(name)
    return found


def _integer(value: Any, name: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise InvalidInput(f"{name} must be an integer {lo}..{hi}, got {short(value)}")
    return value


@dataclass(frozen=True)
class EncodedChunk:
    data: bytes
    key: bool
    timestamp_us: int
    encode_ms: float  # RGBA in, chunk out: the colour conversion and the encoder


_failed_to_open: set[str] = set()  # hardware encoders that did not open in this process
_failed_lock = threading.Lock()


class VideoEncoder:
    """One video stream of ``width`` x ``height`` (even numbers: 4:2:0 halves both) at up to
    ``fps`` frames a second. Not thread-safe: one thread encodes, the same one closes."""

    def __init__(self, request: VideoRequest, width: int, height: int, fps: float):
        if width % 2 or height % 2 or width < 16 or height < 16:
            raise InvalidInput(f"a video frame's width and height must be even and at least 16, got {width}x{height}")
        self.request, self.width, self.height, self.fps = request, width, height, fps
        candidates = [request.encoder] if request.encoder else available_encoders(request.format)
        reasons = []
        for name in candidates:
            with _failed_lock:
                if name in HARDWARE and name in _failed_to_open and request.encoder is None:
                    continue
            try:
                self._context = self._open(name)
            except (av.FFmpegError, ValueError) as exc:
                reasons.append(f"{name}: {exc}")
                if name in HARDWARE:
                    with _failed_lock:
                        _failed_to_open.add(name)
                continue
            self.name = name
            self.hardware = name in HARDWARE
            break
        else:
            raise InvalidInput(f"no {request.format} encoder opens for {width}x{height}: "
                               + ("; ".join(reasons) or "none in this FFmpeg build"))
        self.codec: str | None = None if request.format == "h264" else _codec_string(request.format, width, height, fps)
        self._last_pts = -1

    def _open(self, name: str):
        request = self.request
        context = av.CodecContext.create(name, "w")
        context.width, context.height = self.width, self.height
        context.pix_fmt = "yuv420p"
        context.time_base = TIME_BASE
        context.framerate = Fraction(self.fps).limit_denominator(1000)
        context.gop_size = NO_AUTOMATIC_KEYFRAMES
        context.max_b_frames = 0
        context.thread_count = 0  # the encoder's own choice (libx264: sliced threads for zerolatency)
        # BT.709, limited range: the colour description written into the stream.
        context.colorspace, context.color_primaries, context.color_trc, context.color_range = 1, 1, 1, 1
        options = dict(_ENCODER_OPTIONS[name])
        if request.bitrate is not None:
            context.bit_rate = request.bitrate
            # A rate cap over half a second: a keyframe may exceed a frame's share, a few frames
            # later the rate is back, and no second-long burst fills the client's link.
            options.update({"maxrate": str(request.bitrate), "bufsize": str(request.bitrate // 2)})
        else:
            options.update(_constant_quality(name, request.crf))
        if name == "libx264":
            options["preset"] = request.preset
        if name == "libsvtav1":
            os.environ.setdefault("SVT_LOG", "1")  # errors only: SVT-AV1 otherwise prints a banner per stream
        context.options = options
        context.open()
        return context

    def encode(self, rgba: np.ndarray, timestamp_us: int, key: bool) -> EncodedChunk:
        """``rgba``: (height, width, 4) uint8 of this stream's size; ``key`` forces a keyframe.
        Timestamps must rise; one that does not is moved just past the last."""
        start = time.perf_counter()
        rgba = np.ascontiguousarray(rgba)
        if rgba.shape != (self.height, self.width, 4):
            raise ValueError(f"a {self.width}x{self.height} stream was given a frame of shape {rgba.shape}")
        frame = av.VideoFrame.from_ndarray(rgba, format="rgba").reformat(
            format="yuv420p", dst_colorspace=Colorspace.ITU709, dst_color_range=ColorRange.MPEG)
        frame.pts = self._last_pts = max(int(timestamp_us), self._last_pts + 1)
        frame.time_base = TIME_BASE
        if key:
            frame.pict_type = av.video.frame.PictureType.I
        packets = self._context.encode(frame)
        if len(packets) != 1:
            raise RuntimeError(f"{self.name} gave {len(packets)} packets for one frame; a low-latency "
                               "encoder must give exactly one")
        packet = packets[0]
        data = bytes(packet)
        if self.codec is None:  # H.264: the first chunk is a keyframe and carries the SPS
            self.codec = h264_codec_string(data)
        return EncodedChunk(data, bool(packet.is_keyframe), int(packet.pts), (time.perf_counter() - start) * 1e3)

    def close(self) -> None:
        context, self._context = getattr(self, "_context", None), None
        if context is not None and context.is_open:
            try:
                context.encode(None)  # end of stream: SVT-AV1 complains of a stream closed without one
            except av.FFmpegError:
                pass  # nothing was encoded yet: the encoder has no stream to end, which is what we want


_ENCODER_OPTIONS: dict[str, dict[str, str]] = {
    "libx264": {"tune": "zerolatency", "forced-idr": "1", "sc_threshold": "0", "bf": "0"},
    "h264_nvenc": {"preset": "p1", "tune": "ull", "zerolatency": "1", "delay": "0", "forced-idr": "1",
                   "no-scenecut": "1", "bf": "0"},
    "av1_nvenc": {"preset": "p1", "tune": "ull", "zerolatency": "1", "delay": "0", "forced-idr": "1",
                  "no-scenecut": "1", "bf": "0"},
    "libvpx-vp9": {"deadline": "realtime", "cpu-used": "8", "lag-in-frames": "0", "row-mt": "1",
                   "error-resilient": "0"},
    "libsvtav1": {"preset": "10", "svtav1-params": "pred-struct=1:scd=0"},
}


def _constant_quality(name: str, crf: int) -> dict[str, str]:
    if name.endswith("_nvenc"):
        return {"rc": "vbr", "cq": str(crf), "b": "0"}
    if name == "libvpx-vp9":
        return {"crf": str(crf), "b": "0"}
    return {"crf": str(crf)}


def h264_codec_string(annex_b: bytes) -> str:
    """``avc1.PPCCLL`` from the first SPS in an Annex B access unit: profile, constraint flags, level."""
    at = 0
    while True:
        at = annex_b.find(b"\x00\x00\x01", at)
        if at < 0 or at + 6 >= len(annex_b):
            raise ValueError("no SPS in this H.264 access unit (is it a keyframe?)")
        if annex_b[at + 3] & 0x1F == 7:
            profile, constraints, level = annex_b[at + 4:at + 7]
            return f"avc1.{profile:02X}{constraints:02X}{level:02X}"
        at += 3


# (level, largest picture in luma samples, luma samples a second), lowest first.
_VP9_LEVELS = ((10, 36864, 829440), (11, 73728, 2764800), (20, 122880, 4608000), (21, 245760, 9216000),
               (30, 552960, 20736000), (31, 983040, 36864000), (40, 2228224, 83558400),
               (41, 2228224, 160432128), (50, 8912896, 311951360), (51, 8912896, 588251136),
               (52, 8912896, 1176502272), (60, 35651584, 1176502272), (61, 35651584, 2353004544),
               (62, 35651584, 4706009088))
# (seq_level_idx, largest picture, luma samples a second): AV1 levels 2.0 .. 6.3.
_AV1_LEVELS = ((0, 147456, 4423680), (1, 278784, 8363520), (4, 665856, 19975680), (5, 1065024, 31950720),
               (8, 2359296, 70778880), (9, 2359296, 141557760), (12, 8912896, 267386880),
               (13, 8912896, 534773760), (14, 8912896, 1069547520), (16, 35651584, 1069547520),
               (17, 35651584, 2139095040), (18, 35651584, 4278190080))


def _codec_string(fmt: str, width: int, height: int, fps: float) -> str:
    """VP9 profile 0 or AV1 main profile, 8 bits, at the lowest level that holds the stream."""
    picture, rate = width * height, width * height * math.ceil(fps)
    levels = _VP9_LEVELS if fmt == "vp9" else _AV1_LEVELS
    level = next((lv for lv, most, per_s in levels if picture <= most and rate <= per_s), levels[-1][0])
    return f"vp09.00.{level:02d}.08" if fmt == "vp9" else f"av01.0.{level:02d}M.08"


class VideoStream:
    """One client's video: an encoder on a thread of its own, opened anew (its first chunk a
    keyframe) when the frame size or the settings change or ``restart`` was called, with a
    keyframe at least every ``keyframe_s`` seconds and after ``request_keyframe``.

    Called from one event loop, one ``encode`` at a time; the encoder itself runs only on the
    thread, so neither the loop nor the engine waits for it."""

    def __init__(self) -> None:
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sdfserver-video")
        self._encoder: VideoEncoder | None = None
        self._stream_key: tuple | None = None
        self._restart = False
        self._key_wanted = False
        self._started_at = 0.0
        self._last_key_at: float | None = None

    @property
    def codec(self) -> str | None:
        """The WebCodecs codec string of the stream being encoded."""
        return None if self._encoder is None else self._encoder.codec

    def request_keyframe(self) -> None:
        self._key_wanted = True

    def restart(self) -> None:
        self._restart = True

    async def encode(self, rgba: np.ndarray, request: VideoRequest, fps: float,
                     now: float) -> tuple[VideoEncoder | None, EncodedChunk]:
        """The chunk of one frame (rendered at ``time.monotonic()`` ``now``), and the encoder when
        this chunk starts a new stream. An odd width or height loses its last column or row (4:2:0)."""
        loop = asyncio.get_running_loop()
        height, width = rgba.shape[0] & ~1, rgba.shape[1] & ~1
        key = request.stream_key(width, height, fps)
        started = None
        if self._encoder is None or key != self._stream_key or self._restart:
            old, self._encoder, self._restart = self._encoder, None, False
            started = await loop.run_in_executor(self._thread, _reopen, old, request, width, height, fps)
            self._encoder, self._stream_key, self._started_at, self._last_key_at = started, key, now, None
        force = self._key_wanted or self._last_key_at is None or now - self._last_key_at >= request.keyframe_s
        self._key_wanted = False
        timestamp_us = round((now - self._started_at) * 1e6)
        chunk = await loop.run_in_executor(self._thread, self._encoder.encode, rgba[:height, :width],
                                           timestamp_us, force)
        if chunk.key:
            self._last_key_at = now
        return started, chunk

    def release(self) -> None:
        """Ends the encoder (after any encode in flight, on its thread, without waiting for it);
        the next ``encode`` starts a new stream."""
        encoder, self._encoder = self._encoder, None
        if encoder is not None:
            self._thread.submit(encoder.close)

    def close(self) -> None:
        self.release()
        self._thread.shutdown(wait=False)


def _reopen(old: VideoEncoder | None, request: VideoRequest, width: int, height: int, fps: float) -> VideoEncoder:
    if old is not None:
        old.close()
    return VideoEncoder(request, width, height, fps)


def video_message(world_id: str, encoder: VideoEncoder) -> dict[str, Any]:
    """The ``video`` message that goes before a new stream's first chunk: what a WebCodecs
    ``VideoDecoder.configure`` needs (``codec``; no ``description``, see the module's docstring)
    and which encoder serves it."""
    request = encoder.request
    return {"type": "video", "world": world_id, "format": request.format, "codec": encoder.codec,
            "encoder": encoder.name, "hardware": encoder.hardware, "width": encoder.width,
            "height": encoder.height, "bitrate": request.bitrate, "crf": request.crf,
            "keyframe_s": request.keyframe_s, "bitstream": BITSTREAMS[request.format]}


# How chunks are framed: H.264 access units with start codes, VP9 frames, AV1 temporal units (OBUs).
BITSTREAMS = {"h264": "annexb", "vp9": "vp9", "av1": "obu"}
