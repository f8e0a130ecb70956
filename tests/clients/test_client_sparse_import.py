"""A real world in through the Python client: an array imported as a sparse world, its field
exact, and exported back through the client in every format (the sparse snapshot with its
version); a generated sparse world made with ``create_world(storage=, generate=)``."""

from __future__ import annotations

import numpy as np
from clients_support import oracle_distance

from sdfclient import Client


def test_a_sparse_world_from_an_imported_array_exports_through_the_client(server_url, tmp_path):
    rng = np.random.default_rng()
    voxels = np.zeros((24, 20, 40), np.uint8)  # (z, y, x): grown to 48 x 32 x 32
    voxels[:, :3, :] = 0x92
    z, y, x = np.indices(voxels.shape)
    for _ in range(3):
        c, r = rng.integers(0, voxels.shape), int(rng.integers(2, 6))
        voxels[(z - c[0]) ** 2 + (y - c[1]) ** 2 + (x - c[2]) ** 2 <= r * r] = rng.integers(1, 256)
    grown = np.zeros((32, 32, 48), np.uint8)
    grown[:24, :20, :40] = voxels
    with Client(server_url) as client:
        world = client.import_world(voxels, storage="sparse", chunk_size=16, max_distance=5)
        assert world.storage == "sparse" and world.size == (48, 32, 32) and world.version >= 1
        field = client.read_field(world.id, min_version=world.version)
        np.testing.assert_array_equal(field.data, oracle_distance(grown, 5))

        snapshot = client.export_world(world.id, path=tmp_path / "world.sdfsnap")
        assert snapshot.version == world.version and snapshot.data[:8] == b"SDFSNAP1"
        np.testing.assert_array_equal(client.export_world(world.id, "npy").array, grown)
        copy = client.import_world(tmp_path / "world.sdfsnap")
        assert copy.storage == "sparse" and copy.size == world.size
        np.testing.assert_array_equal(client.read_voxels(copy.id).data, grown)
        for w in (world, copy):
            client.delete_world(w.id)


def test_create_world_takes_storage_and_generate(server_url):
    with Client(server_url) as client:
        world = client.create_world((64, 32, 64), max_distance=8, storage="sparse",
                                    generate={"kind": "terrain", "seed": 3, "base": 12, "amplitude": 4})
        try:
            assert world.storage == "sparse" and world.raw["generate"]["seed"] == 3
            voxels = client.read_voxels(world.id).data
            assert voxels[:, :4].any() and not voxels[:, -4:].any()  # (z, y, x): ground below, air above
        finally:
            client.delete_world(world.id)
