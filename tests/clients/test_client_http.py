"""sdfclient against a real ``sdfserver serve`` process on loopback."""

from __future__ import annotations

import asyncio
import secrets

import numpy as np
import pytest
from clients_support import apply_edits, oracle_distance, random_batch

from sdfclient import AsyncClient, Client, InvalidEdit, InvalidInput, NotFound, ServerError, edits

SIZE = (48, 32, 32)  # x, y, z
CAP = 12


@pytest.fixture
def client(server_url):
    with Client(server_url) as c:
        yield c


@pytest.fixture
def world(client):
    info = client.create_world(SIZE, chunk_size=16, max_distance=CAP)
    yield info
    try:
        client.delete_world(info.id)
    except NotFound:
        pass


def test_world_round_trip(client, world):
    assert world.version == 0 and world.size == SIZE and world.chunk_size == 16
    assert world.max_distance == CAP and world.algorithm == "exact"
    assert client.get_world(world.id) == world
    assert world.id in [w.id for w in client.list_worlds()]

    updated = client.update_world(world.id, algorithm="brute", max_distance=9)
    assert (updated.algorithm, updated.max_distance) == ("brute", 9)
    assert client.get_world(world.id).max_distance == 9

    client.delete_world(world.id)
    assert world.id not in [w.id for w in client.list_worlds()]
    with pytest.raises(NotFound):
        client.get_world(world.id)


def test_fields_equal_the_oracle_after_random_edits(client, world):
    seed = secrets.randbits(32)
    rng = np.random.default_rng(seed)
    expected = np.zeros(SIZE[::-1], dtype=np.uint8)
    version = 0
    for _ in range(6):
        batch = random_batch(rng, SIZE)
        apply_edits(expected, batch)
        version = client.edit(world.id, batch)
    assert version == 6, seed

    field = client.read_field(world.id, min_version=version)
    assert field.version >= version and field.origin == (0, 0, 0)
    assert field.shape == SIZE[::-1] and field.data.dtype == np.uint8
    np.testing.assert_array_equal(field.distance, oracle_distance(expected, CAP), err_msg=f"seed {seed}")
    voxels = client.read_voxels(world.id)
    np.testing.assert_array_equal(voxels.data, expected, err_msg=f"seed {seed}")

    lo, hi = (5, 3, 7), (37, 19, 30)
    part = client.read_field(world.id, (lo, hi), format="packed", min_version=version)
    assert part.origin == lo and part.data.dtype == np.uint16 and part.shape == (23, 16, 32)
    np.testing.assert_array_equal(part.distance, field.distance[7:30, 3:19, 5:37], err_msg=f"seed {seed}")
    solid = expected[7:30, 3:19, 5:37] != 0
    np.testing.assert_array_equal(part.colour[solid], expected[7:30, 3:19, 5:37][solid])


def test_query_gives_the_field_at_points(client, world):
    version = client.edit(world.id, [edits.box((0, 0, 0), (48, 2, 32), colour=7)])
    points = np.array([[10, y, 12] for y in range(0, 12)] + [[47, 31, 31], [0, 0, 0]])
    result = client.query(world.id, points + 0.5, min_version=version)  # voxel centres
    field = client.read_field(world.id, min_version=version).distance
    expected = field[points[:, 2], points[:, 1], points[:, 0]]
    np.testing.assert_allclose(result.distances, expected)
    assert result.gradients.shape == (len(points), 3) and np.isfinite(result.gradients).all()
    # Above a floor the way away from it is +y.
    above = result.gradients[3:10]
    assert (above[:, 1] > 0).all() and np.allclose(above[:, [0, 2]], 0)


def test_errors_carry_the_server_code_and_change_nothing(client, world):
    with pytest.raises(NotFound) as info:
        client.get_world("no-such-world")
    assert info.value.status == 404 and info.value.code == "not_found" and info.value.message
    with pytest.raises(NotFound):
        client.edit("no-such-world", [edits.sphere((1, 1, 1), 1)])
    with pytest.raises(NotFound):
        client.read_field("no-such-world")

    before = client.get_world(world.id).version
    outside = np.array([[1, 1, 1, 5], [48, 0, 0, 5]])  # x = 48 is outside the world
    with pytest.raises(InvalidEdit) as info:
        client.edit(world.id, [edits.sphere((4, 4, 4), 2), edits.voxels(outside)])
    assert info.value.status == 422 and info.value.code == "invalid_edit"
    assert client.get_world(world.id).version == before
    assert not client.read_voxels(world.id).data.any()

    with pytest.raises(InvalidInput) as info:
        client.create_world((40, 32, 32), chunk_size=16)  # not a multiple of the chunk size
    assert info.value.status == 422
    with pytest.raises(ServerError) as info:
        client.read_field(world.id, ((0, 0, 0), (64, 64, 64)))  # outside the world
    assert 400 <= info.value.status < 500


def test_async_client_concurrent_batches_get_distinct_versions(server_url):
    async def run() -> tuple[list[int], np.ndarray, np.ndarray]:
        async with AsyncClient(server_url) as client:
            info = await client.create_world((32, 32, 32), chunk_size=16, max_distance=CAP)
            try:
                points = [(4 * i + 2, 16, 16) for i in range(8)]
                versions = await asyncio.gather(*(
                    client.edit(info.id, [edits.sphere(p, 1, colour=i + 1)]) for i, p in enumerate(points)))
                field = await client.read_field(info.id, min_version=max(versions))
                voxels = await client.read_voxels(info.id)
                return list(versions), field.distance, voxels.data
            finally:
                await client.delete_world(info.id)

    versions, distance, voxels = asyncio.run(run())
    assert sorted(versions) == list(range(1, 9))
    np.testing.assert_array_equal(distance, oracle_distance(voxels, CAP))
    assert set(np.unique(voxels)) == set(range(9))


def test_field_options_through_the_client(client):
    """Every creation option the server takes reaches it from create_world, and update_world
    PATCHes metric, sign and placement; an option the server does not take is refused here."""
    world = client.create_world((32, 16, 16), chunk_size=8, max_distance=9, metric="euclidean", signed=True,
                                voxel_size=0.5, origin=(1, 2, 3), palette=[(i, 255 - i, 7) for i in range(255)])
    try:
        assert (world.metric, world.signed, world.voxel_size, world.origin) == ("euclidean", True, 0.5,
                                                                               (1.0, 2.0, 3.0))
        assert world.raw["palette"][3] == [3, 252, 7]
        version = client.edit(world.id, [edits.box((4, 4, 4), (8, 8, 8), 9)])
        field = client.read_field(world.id, min_version=version)
        assert field.data.dtype == np.float32 and field.data[6, 6, 6] < 0  # inside the box
        changed = client.update_world(world.id, metric="manhattan", origin=(0, 0, 0))
        assert (changed.metric, changed.signed, changed.origin) == ("manhattan", True, (0.0, 0.0, 0.0))
        assert client.read_field(world.id, min_version=version).data.dtype == np.int16
        with pytest.raises(InvalidInput, match="metric"):
            client.update_world(world.id, metric="chebyshev")
        with pytest.raises(ValueError, match="no option 'colour'"):
            client.create_world((16, 16, 16), colour=3)
    finally:
        client.delete_world(world.id)
