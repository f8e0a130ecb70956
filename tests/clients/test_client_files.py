"""Import, export and rendered frames through the client, against a real server: export -> import
round trips in every format keep the voxels; frames decode, carry the field version, and show
the colours the renderer's integer shading gives."""

from __future__ import annotations

import asyncio
import io

import numpy as np
import pytest
from clients_support import oracle_distance, random_batch
from PIL import Image

from sdfclient import AsyncClient, Camera, Client, InvalidInput, edits

SIZE, CAP = (32, 32, 16), 20


@pytest.fixture(scope="module")
def world(server_url):
    """A world with random edits (fresh seed) and a solid floor; its voxels and version."""
    rng = np.random.default_rng()
    with Client(server_url) as client:
        info = client.create_world(SIZE, chunk_size=16, max_distance=CAP)
        for _ in range(4):
            client.edit(info.id, random_batch(rng, SIZE))
        version = client.edit(info.id, [edits.box((0, 0, 0), (SIZE[0], 2, SIZE[2]), 0xAE)])
        voxels = client.read_voxels(info.id, min_version=version).data
        assert (voxels != 0).any() and (voxels == 0).any()
        yield info, voxels, version
        client.delete_world(info.id)


def test_export_import_round_trips(server_url, world, tmp_path):
    info, voxels, version = world
    with Client(server_url) as client:
        made = []
        try:
            snapshot = client.export_world(info.id, "snapshot", path=tmp_path / "w.sdfsnap")
            assert snapshot.version == version and snapshot.filename == f"{info.id}.sdfsnap"
            assert (tmp_path / "w.sdfsnap").read_bytes() == snapshot.data
            copy = client.import_world(tmp_path / "w.sdfsnap")  # the server tells the format
            made.append(copy.id)
            assert (copy.size, copy.chunk_size, copy.max_distance, copy.algorithm, copy.version) == \
                (info.size, info.chunk_size, info.max_distance, info.algorithm, 1)
            np.testing.assert_array_equal(client.read_voxels(copy.id).data, voxels)
            field = client.read_field(copy.id, min_version=1)
            np.testing.assert_array_equal(field.distance, oracle_distance(voxels, CAP))

            array = client.export_world(info.id, "npy").array
            assert array.dtype == np.uint8 and array.shape == SIZE[::-1]
            np.testing.assert_array_equal(array, voxels)
            np.save(tmp_path / "w.npy", array)
            from_path = client.import_world(str(tmp_path / "w.npy"), chunk_size=8, max_distance=7)
            made.append(from_path.id)
            assert from_path.chunk_size == 8 and from_path.max_distance == 7
            np.testing.assert_array_equal(client.read_voxels(from_path.id).data, voxels)

            vox = client.export_world(info.id, "vox")
            assert vox.data[:4] == b"VOX " and vox.version == version
            from_vox = client.import_world(vox.data)
            made.append(from_vox.id)
            np.testing.assert_array_equal(client.read_voxels(from_vox.id).data, voxels)

            # An array uploads as .npy; a size that is not whole chunks grows with air.
            odd = voxels[:, :13, :29]
            grown = client.import_world(odd, chunk_size=16)
            made.append(grown.id)
            assert grown.size == (32, 16, 16)
            got = client.read_voxels(grown.id).data
            np.testing.assert_array_equal(got[:, :13, :29], odd)
            assert not got[:, 13:, :].any() and not got[:, :, 29:].any()
        finally:
            for world_id in made:
                client.delete_world(world_id)


def test_import_refusals(server_url, world, tmp_path):
    info, _, _ = world
    with Client(server_url) as client:
        before = {w.id for w in client.list_worlds()}
        with pytest.raises(InvalidInput):
            client.import_world(b"not a snapshot at all", "snapshot")
        with pytest.raises(InvalidInput):
            client.import_world(b"\x93NUMPY garbage", "npy")
        with pytest.raises(InvalidInput, match="npy"):
            client.import_world(b"...")  # no format's magic
        snapshot = client.export_world(info.id).data
        (tmp_path / "w.bin").write_bytes(snapshot)
        with pytest.raises(InvalidInput, match="format=npy"):
            client.import_world(tmp_path / "w.bin", "npy")  # the content is a snapshot
        with pytest.raises(ValueError):
            client.import_world(snapshot, chunk_size=8)
        with pytest.raises(ValueError):
            client.import_world(snapshot, "tar")
        assert {w.id for w in client.list_worlds()} == before


# RGB332 colours as the renderer shows a top face (256/256): r, g * 255 // 7, b * 85.
FLOOR, FLOOR_RGB = 0xAE, (5 * 255 // 7, 3 * 255 // 7, 2 * 85)
BLOCK, BLOCK_RGB = 0x1C, (0, 255, 0)


def test_render_frames(server_url):
    down = Camera((16.0, 24.0, 8.0), pitch_deg=-90, fov_y_deg=40, width=48, height=32)
    with Client(server_url) as client:
        info = client.create_world(SIZE, chunk_size=16, max_distance=CAP)
        try:
            version = client.edit(info.id, [edits.box((0, 0, 0), (32, 2, 16), FLOOR),
                                            edits.box((12, 2, 4), (20, 6, 12), BLOCK)])
            client.read_field(info.id, min_version=version)  # the frame shows a computed field
            png = client.render(info.id, down, format="png")
            rgba = client.render(info.id, down, format="rgba")
            jpeg = client.render(info.id, down, format="jpeg", quality=90, ambient_occlusion=True)
            hit = client.pick(info.id, down, 24.5, 16.5)  # just off the centre: x > 16, z > 8
            sky = client.pick(info.id, Camera((16.0, 24.0, 8.0), pitch_deg=60, width=48, height=32), 24, 16)
            with pytest.raises(TypeError):
                client.render(info.id, down, brightness=2)
            with pytest.raises(InvalidInput):
                client.render(info.id, Camera((16.0, 24.0, 8.0), width=0, height=32))
        finally:
            client.delete_world(info.id)

    assert png.format == "png" and png.data[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.field_version == version == 1 and (png.width, png.height) == (48, 32)
    assert png.render_ms is not None and png.render_ms >= 0
    with Image.open(io.BytesIO(png.data)) as image:
        assert image.format == "PNG" and image.size == (48, 32)
    pixels = png.pixels
    assert pixels.shape == (32, 48, 4) and (pixels[..., 3] == 255).all()
    np.testing.assert_array_equal(rgba.pixels, pixels)  # PNG is lossless: the same frame
    # Looking straight down: the block's top in the middle, the floor at the corners.
    assert tuple(pixels[16, 24, :3]) == BLOCK_RGB
    for y, x in ((0, 0), (0, 47), (31, 0), (31, 47)):
        assert tuple(pixels[y, x, :3]) == FLOOR_RGB
    block = (pixels[..., :3] == BLOCK_RGB).all(axis=-1)
    floor = (pixels[..., :3] == FLOOR_RGB).all(axis=-1)
    assert (block | floor).all() and 0.1 < block.mean() < 0.5
    assert jpeg.data[:2] == b"\xff\xd8" and jpeg.pixels.shape == (32, 48, 4) and jpeg.field_version == 1
    assert (hit.voxel, hit.normal, hit.place, hit.field_version) == ((16, 5, 8), (0, 1, 0), (16, 6, 8), 1)
    assert sky is None


def test_async_client_files(server_url, world):
    info, voxels, version = world

    async def run():
        async with AsyncClient(server_url) as client:
            exported = await client.export_world(info.id, "npy")
            copy = await client.import_world(exported.array, max_distance=9)
            try:
                got = (await client.read_voxels(copy.id)).data
                view = Camera.look_at((40, 30, 40), (16, 0, 8), width=24, height=16)
                await client.read_field(copy.id, min_version=1)
                frame = await client.render(copy.id, view)
                async with client.stream(copy.id) as stream:  # the same view, pushed as frames
                    await stream.set_camera(view, format="png", max_fps=30)
                    pushed = await asyncio.wait_for(_first_frame(stream), 30)
            finally:
                await client.delete_world(copy.id)
        return exported, copy, got, frame, pushed

    exported, copy, got, frame, pushed = asyncio.run(run())
    assert exported.version == version and copy.max_distance == 9
    np.testing.assert_array_equal(got, voxels)
    assert frame.field_version == 1 and frame.pixels.shape == (16, 24, 4)
    raw = pushed.raw
    assert (raw["format"], raw["width"], raw["height"], pushed.version) == ("png", 24, 16, 1)
    assert raw["data"] == frame.data  # the same view of the same field, the same PNG


async def _first_frame(stream):
    async for message in stream:
        if message.type == "frame":
            return message
