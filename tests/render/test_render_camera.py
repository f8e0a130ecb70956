import io
import math

import numpy as np
import pytest
from PIL import Image

from sdfserver.errors import InvalidInput, TooLarge
from sdfserver.render import Camera, encode_frame, format_from_accept, parse_view


def test_look_at_points_forward_at_target():
    rng = np.random.default_rng()
    for _ in range(20):
        position, target = rng.uniform(-50, 50, 3), rng.uniform(-50, 50, 3)
        camera = Camera.look_at(tuple(position), tuple(target), width=8, height=8).validated()
        _, forward, right, up = camera.basis()
        expected = (target - position) / np.linalg.norm(target - position)
        assert np.allclose(forward, expected, atol=1e-3)  # pitch clamps at 89.9 degrees
        assert abs(np.dot(right, forward)) < 1e-9 and abs(np.dot(up, forward)) < 1e-9
        assert up[1] >= 0


def test_yaw_zero_looks_along_minus_z_and_right_is_plus_x():
    _, forward, right, up = Camera((0.0, 0.0, 0.0), 0.0, 0.0, 90.0, 200, 100).basis()
    assert np.allclose(forward, [0, 0, -1]) and np.allclose(up, [0, 1, 0])
    assert np.allclose(right, [2, 0, 0])  # tan(45 deg) * aspect 2


@pytest.mark.parametrize("bad", [
    {"position": [0, 0, math.nan]}, {"position": [0, 0]}, {"position": [0, 0, 0], "yaw_deg": "x"},
    {"position": [0, 0, 0], "fov_y_deg": 0}, {"position": [0, 0, 0], "width": 0},
    {"position": [0, 0, 0], "width": 1.5}, {"position": [0, 0, 0], "pitch_deg": 91},
    {"position": [0, 0, 0], "target": [0, 0, 0]}, {"position": [0, 0, 0], "colour": 3},
    {"yaw_deg": 0}, {"position": [0, 0, 0], "sky_rgb": -1}, {"position": [0, 0, 0], "shadows": 1},
    [1, 2, 3],
])
def test_parse_view_rejects_bad_input(bad):
    with pytest.raises(InvalidInput):
        parse_view(bad)


def test_parse_view_size_limit_is_too_large():
    with pytest.raises(TooLarge):
        parse_view({"position": [0, 0, 0], "width": 8000, "height": 100})


def test_parse_view_accepts_target_and_options():
    camera, options = parse_view({"position": [1, 2, 3], "target": [4, 2, 3], "width": 32, "height": 16,
                                  "shadows": True, "highlight": [1, 1, 1], "highlight_radius": 2})
    assert camera.yaw_deg == pytest.approx(90.0) and camera.pitch_deg == pytest.approx(0.0)
    assert options.shadows and options.highlight == (1, 1, 1)


def test_encoders_round_trip():
    rng = np.random.default_rng()
    pixels = rng.integers(0, 256, (12, 20, 4), dtype=np.uint8)
    pixels[..., 3] = 255
    assert encode_frame(pixels, "rgba") == pixels.tobytes()
    png = np.asarray(Image.open(io.BytesIO(encode_frame(pixels, "png"))))
    assert np.array_equal(png, pixels)
    jpeg = Image.open(io.BytesIO(encode_frame(pixels, "jpeg", quality=90)))
    assert jpeg.format == "JPEG" and jpeg.size == (20, 12)
    with pytest.raises(InvalidInput):
        encode_frame(pixels, "gif")


def test_format_from_accept():
    assert format_from_accept("image/png, image/jpeg;q=0.5") == "png"
    assert format_from_accept("application/octet-stream") == "rgba"
    assert format_from_accept("*/*") == "jpeg" and format_from_accept(None) == "jpeg"
