"""render/video.py's encoders on their own: every format decodes back (FFmpeg's decoders), one
chunk a frame at once, keyframes only where forced, codec strings that name the stream, a bitrate
that holds, and NVENC falling back to the CPU encoder."""

from __future__ import annotations

import av
import numpy as np
import pytest

from sdfserver.errors import InvalidInput
from sdfserver.render import video
from sdfserver.render.video import VideoEncoder, h264_codec_string, parse_video_request

DECODERS = {"h264": ("h264", {}), "vp9": ("vp9", {}), "av1": ("libdav1d", {"max_frame_delay": "1"})}
WIDTH, HEIGHT = 160, 96


def pictures(count: int, seed: int) -> list[np.ndarray]:
    """Smooth gradients under a moving textured block: each frame differs from the last."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH]
    texture = rng.integers(0, 256, (24, 32, 3))
    out = []
    for i in range(count):
        rgba = np.empty((HEIGHT, WIDTH, 4), np.uint8)
        rgba[..., 0], rgba[..., 1], rgba[..., 2], rgba[..., 3] = (x + 2 * i) % 256, y * 2, 128 + y, 255
        left = (5 * i) % (WIDTH - 32)
        rgba[30:54, left:left + 32, :3] = texture
        out.append(rgba)
    return out


def luma_psnr(decoded: np.ndarray, reference: np.ndarray) -> float:
    error = (decoded.astype(float) - reference[..., :3].astype(float)) @ [0.2126, 0.7152, 0.0722]
    return 10 * np.log10(255 ** 2 / np.mean(error ** 2))


@pytest.mark.parametrize("fmt", video.VIDEO_FORMATS)
def test_each_format_decodes_back_one_chunk_a_frame_with_keyframes_only_where_forced(fmt):
    encoder = VideoEncoder(parse_video_request({}, fmt), WIDTH, HEIGHT, 60)
    assert encoder.name in video.ENCODERS[fmt] and encoder.hardware == (encoder.name in video.HARDWARE)
    name, options = DECODERS[fmt]
    decoder = av.CodecContext.create(name, "r")
    decoder.options = dict(options)
    forced = {0, 7, 15}
    try:
        for i, picture in enumerate(pictures(20, seed=len(fmt))):
            chunk = encoder.encode(picture, i * 16_667, key=i in forced)
            assert chunk.key == (i in forced), i
            assert chunk.timestamp_us == i * 16_667 and chunk.encode_ms > 0
            decoded = decoder.decode(av.Packet(chunk.data))
            assert len(decoded) == 1, f"chunk {i} gave {len(decoded)} pictures"
            assert luma_psnr(decoded[0].to_ndarray(format="rgb24"), picture) >= 35.0, i
    finally:
        encoder.close()
    prefix = {"h264": "avc1.", "vp9": "vp09.00.", "av1": "av01.0."}[fmt]
    assert encoder.codec.startswith(prefix) and encoder.codec.endswith("" if fmt == "h264" else ".08")


def test_the_h264_codec_string_is_read_from_the_sps():
    sps = bytes([0, 0, 0, 1, 0x67, 0x64, 0x00, 0x1F, 0xAC]) + bytes([0, 0, 1, 0x68, 0xEE])
    assert h264_codec_string(bytes([0, 0, 0, 1, 0x09, 0xF0]) + sps) == "avc1.64001F"
    with pytest.raises(ValueError, match="no SPS"):
        h264_codec_string(bytes([0, 0, 0, 1, 0x41, 0x9A]))


@pytest.mark.parametrize("fmt, size, fps, codec", [
    ("vp9", (1280, 720), 60, "vp09.00.40.08"), ("vp9", (1920, 1080), 60, "vp09.00.41.08"),
    ("av1", (1280, 720), 60, "av01.0.08M.08"), ("av1", (1920, 1080), 60, "av01.0.09M.08"),
])
def test_vp9_and_av1_codec_strings_name_the_level_the_stream_needs(fmt, size, fps, codec):
    assert video._codec_string(fmt, *size, fps) == codec


@pytest.mark.parametrize("name", ["libx264", "libvpx-vp9", "libsvtav1"])
def test_a_bitrate_holds_at_max_fps(name):
    fmt = {"libx264": "h264", "libvpx-vp9": "vp9", "libsvtav1": "av1"}[name]
    encoder = VideoEncoder(parse_video_request({"bitrate": 1_000_000, "encoder": name}, fmt), WIDTH, HEIGHT, 30)
    rng = np.random.default_rng(3)
    noise = rng.integers(0, 256, (HEIGHT, WIDTH, 4), np.uint8)  # costly to code: the rate limits it
    sizes = [len(encoder.encode(np.roll(noise, 3 * i, axis=1), i * 33_333, key=i == 0).data) for i in range(60)]
    encoder.close()
    mbit_s = sum(sizes[30:]) * 8 / 1.0 / 1e6
    assert 0.6 < mbit_s < 1.4, mbit_s


def test_a_hardware_encoder_that_does_not_open_falls_back_to_the_cpu_one(monkeypatch):
    monkeypatch.setattr(video, "_failed_to_open", set())
    monkeypatch.setitem(video.ENCODERS, "h264", ("h264_nvenc", "libx264"))
    encoder = VideoEncoder(parse_video_request({}, "h264"), WIDTH, HEIGHT, 60)
    try:
        if encoder.name == "h264_nvenc":
            pytest.skip("this machine's NVENC opens")
        assert encoder.name == "libx264" and not encoder.hardware
        assert "h264_nvenc" in video._failed_to_open  # not tried again by the next stream
    finally:
        encoder.close()


@pytest.mark.parametrize("size", [(161, 96), (160, 95), (8, 8)])
def test_odd_or_tiny_sizes_are_refused(size):
    with pytest.raises(InvalidInput, match="even and at least 16"):
        VideoEncoder(parse_video_request({}, "h264"), *size, 60)
