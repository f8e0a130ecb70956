"""Voxel value v is drawn as the world's palette[v - 1]: the default (RGB332 expanded) draws what
the kernel always drew, a palette set at creation or by reconfigure is drawn at once."""

from __future__ import annotations

import numpy as np

from sdfserver.render import Camera, RenderOptions, Renderer
from sdfserver.world_config import rgb332_palette

from .test_render_frames import SKY, analytic_world, make_world, sky_pixel

CAMERA = Camera(((20.5, 10.5, 60.0)), 0.0, 0.0, 60.0, 63, 47).validated()  # the sphere's +z face at the centre


def test_the_default_palette_draws_rgb332(gpu):
    world = make_world(gpu, analytic_world())
    explicit = make_world(gpu, analytic_world(), palette=rgb332_palette())
    renderer = Renderer(gpu)
    a = renderer.render(world, CAMERA, RenderOptions(sky_rgb=SKY, shadows=True)).pixels
    b = renderer.render(explicit, CAMERA, RenderOptions(sky_rgb=SKY, shadows=True)).pixels
    assert np.array_equal(a, b)
    plain = renderer.render(world, CAMERA, RenderOptions(sky_rgb=SKY)).pixels
    assert tuple(plain[23, 31, :3]) == (255 * 166 >> 8, 0, 0)  # 0b111_000_00 is red
    renderer.release()
    world.release()
    explicit.release()


def test_a_palette_change_is_drawn_on_the_next_frame(gpu):
    rng = np.random.default_rng()
    world = make_world(gpu, analytic_world())
    renderer = Renderer(gpu)
    before = renderer.render(world, CAMERA, RenderOptions(sky_rgb=SKY)).pixels
    palette = rng.integers(0, 256, (255, 3)).tolist()
    palette[0b111_000_00 - 1] = [10, 200, 30]
    world.reconfigure(palette=palette)
    after = renderer.render(world, CAMERA, RenderOptions(sky_rgb=SKY)).pixels
    assert tuple(after[23, 31, :3]) == tuple(c * 166 >> 8 for c in (10, 200, 30))
    sky = np.all(before == sky_pixel(), axis=-1)
    assert np.array_equal(sky, np.all(after == sky_pixel(), axis=-1))
    # Every solid pixel is its voxel's palette colour times the face brightness: the floor's top.
    floor = palette[0b011_011_01 - 1]
    assert any(tuple(p) == tuple(floor) for p in after[..., :3].reshape(-1, 3).tolist())
    world.reconfigure(palette=None)
    assert np.array_equal(renderer.render(world, CAMERA, RenderOptions(sky_rgb=SKY)).pixels, before)
    renderer.release()
    world.release()
