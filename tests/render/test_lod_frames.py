"""Level of detail and frames: a field that is never above the truth (``conservative`` outside the
focus) shows exactly the voxels the exact field shows; ``jfa`` outside the focus is never below
the truth, the direction in which a ray can step over a solid (docs/rendering.md)."""

from __future__ import annotations

import numpy as np
import pytest

from sdfserver.render import Camera, RenderOptions, Renderer
from sdfserver.world import Focus, World, WorldConfig

from .test_render_frames import CAMERAS, SKY, analytic_world, random_world


def world_of(gpu, voxels, **config) -> World:
    world = World(gpu, WorldConfig(size=voxels.shape[::-1], chunk_size=8, **config))
    world.load_voxels(voxels)
    world.recompute()
    return world


def frames(gpu, world, cameras):
    renderer = Renderer(gpu)
    out = []
    for position, target, fov in cameras:
        camera = Camera.look_at(position, target, fov_y_deg=fov, width=64, height=48).validated()
        out.append(renderer.render(world, camera, RenderOptions(sky_rgb=SKY), stats=True))
    renderer.release()
    return out


@pytest.mark.parametrize("scene", ["analytic", "random"])
def test_conservative_lod_frames_equal_exact_frames(gpu, scene):
    voxels = analytic_world() if scene == "analytic" else random_world(np.random.default_rng(7), 32, 0.01)
    exact = world_of(gpu, voxels)
    lod = world_of(gpu, voxels, focus=Focus((1, 1, 1), (1, 1, 1)), lod_algorithm="conservative")
    assert set(lod.last_recompute.algorithms) == {"exact", "conservative"}
    # The focus is used: outside it the field is below the exact one somewhere.
    assert (lod.read_distance() < exact.read_distance()).any()
    for a, b in zip(frames(gpu, exact, CAMERAS), frames(gpu, lod, CAMERAS)):
        assert np.array_equal(a.pixels, b.pixels)
        assert b.reads.sum() >= a.reads.sum()  # smaller steps, the same voxels
    exact.release()
    lod.release()


def test_jfa_lod_is_never_below_the_truth(gpu):
    """JFA's field overestimates where it errs: the unsafe direction for rays."""
    voxels = random_world(np.random.default_rng(5), 32, 0.02)
    exact = world_of(gpu, voxels)
    jfa = world_of(gpu, voxels, focus=Focus((1, 1, 1), (1, 1, 1)), lod_algorithm="jfa")
    assert np.all(jfa.read_distance() >= exact.read_distance())
    exact.release()
    jfa.release()
