"""Pictures from the stream's frame messages: JPEG, PNG and raw RGBA frames, and video frames
(``h264``, ``vp9``, ``av1``) decoded with PyAV (``pip install av``).

    decoder = FrameDecoder()
    await stream.set_camera(camera, format="h264", bitrate=4_000_000)
    async for message in stream:
        picture = decoder.feed(message.raw)          # (height, width, 3) uint8 RGB, or None
        if decoder.needs_keyframe:
            await stream.request_keyframe()

A video stream starts with a ``video`` message (codec, encoder, size); each ``frame`` after it is
one encoded chunk (``key``, ``timestamp`` in microseconds): H.264 as Annex B, VP9 frames, AV1
temporal units. Every chunk decodes to one picture at once (the decoders are set for no delay).
A chunk that cannot be decoded (a missed one, or a delta before any keyframe) sets
``needs_keyframe``, and pictures resume at the next keyframe.
"""

from __future__ import annotations

import io
import time
from typing import Any

import numpy as np

VIDEO_FORMATS = ("h264", "vp9", "av1")
_DECODERS = {"h264": ("h264", {}), "vp9": ("vp9", {}), "av1": ("libdav1d", {"max_frame_delay": "1"})}


class FrameDecoder:
    """Decodes one stream's frames in order; one per stream (a video decoder keeps state)."""

    def __init__(self) -> None:
        self._context: Any = None
        self.video: dict[str, Any] | None = None  # the last ``video`` message
        self.needs_keyframe = False
        self.decode_ms = 0.0  # the last frame's decoding time
        self._last_seq: int | None = None

    def feed(self, raw: dict[str, Any]) -> np.ndarray | None:
        """A stream message's picture as (height, width, 3) uint8 RGB; None for messages that
        carry none (``video``, acknowledgements, chunks, ...) and for a video chunk that waits
        for a keyframe."""
        kind = raw.get("type")
        if kind == "video":
            self._open(raw)
            return None
        if kind != "frame":
            return None
        start = time.perf_counter()
        fmt = raw["format"]
        if fmt in VIDEO_FORMATS:
            picture = self._decode_chunk(raw)
        elif fmt == "rgba":
            picture = np.frombuffer(raw["data"], np.uint8).reshape(raw["height"], raw["width"], 4)[..., :3]
        else:
            from PIL import Image

            picture = np.asarray(Image.open(io.BytesIO(raw["data"])).convert("RGB"))
        self.decode_ms = (time.perf_counter() - start) * 1e3
        return picture

    def _open(self, video: dict[str, Any]) -> None:
        import av

        name, options = _DECODERS[video["format"]]
        context = av.CodecContext.create(name, "r")
        context.options = dict(options)
        self._context, self.video = context, video
        self._last_seq = None
        self.needs_keyframe = True  # until this stream's first chunk, a keyframe

    def _decode_chunk(self, raw: dict[str, Any]) -> np.ndarray | None:
        import av

        if self._context is None:
            raise ValueError(f"a {raw['format']} frame before any 'video' message: the stream's "
                             "first message says how to decode it")
        seq = raw.get("seq")
        if self._last_seq is not None and seq is not None and seq != self._last_seq + 1:
            self.needs_keyframe = True  # a chunk was missed: what follows refers to it
        self._last_seq = seq
        if self.needs_keyframe and not raw["key"]:
            return None
        packet = av.Packet(raw["data"])
        packet.pts = raw.get("timestamp")
        try:
            frames = self._context.decode(packet)
        except av.FFmpegError:
            self.needs_keyframe = True
            return None
        self.needs_keyframe = False
        if not frames:
            return None
        return frames[-1].to_ndarray(format="rgb24")


def psnr(decoded: np.ndarray, reference: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of two RGB(A) pictures' colour channels (alpha ignored);
    inf for equal pictures."""
    return _psnr(decoded[..., :3].astype(np.float64) - reference[..., :3].astype(np.float64))


def luma_psnr(decoded: np.ndarray, reference: np.ndarray) -> float:
    """PSNR of the BT.709 luma of two RGB(A) pictures: how video codecs are usually compared, and
    what 4:2:0's halved chroma resolution does not lower."""
    error = decoded[..., :3].astype(np.float64) - reference[..., :3].astype(np.float64)
    return _psnr(error @ np.array([0.2126, 0.7152, 0.0722]))


def _psnr(error: np.ndarray) -> float:
    mse = float(np.mean(error ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(255.0 ** 2 / mse)
