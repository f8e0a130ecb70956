"""Field reads of every metric and sign through sdfclient: a block keeps the dtype the answer
names (uint8, int16, float32, uint16) and its content, and its distance and colour views follow
the content (a Euclidean packed field holds squared distances and no colour); over a mock
transport and against a real server."""

from __future__ import annotations

import httpx
import numpy as np
import pytest
from scipy import ndimage

import sdfclient
from sdfclient import Client, _wire, edits


def answering(body: dict) -> httpx.MockTransport:
    return httpx.MockTransport(lambda request: httpx.Response(
        200, content=_wire.encode(body), headers={"content-type": "application/msgpack"}))


def block_of(data: np.ndarray, content: str, fmt: str) -> sdfclient.Block:
    body = {"origin": [0, 0, 0], "shape": list(data.shape), "dtype": data.dtype.name, "version": 2,
            "content": content, "data": data}
    with Client("http://sdf.test", transport=answering(body)) as client:
        return client.read_field("w", format=fmt)


@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.float32])
def test_a_distance_block_keeps_the_answers_dtype(dtype):
    rng = np.random.default_rng()
    data = (rng.random((2, 3, 4)) * 20 - (10 if dtype != np.uint8 else 0)).astype(dtype)
    block = block_of(data, "distance", "distance")
    assert block.content == "distance" and block.data.dtype == dtype and block.distance.dtype == dtype
    np.testing.assert_array_equal(block.distance, data)


def test_a_euclidean_packed_block_holds_squared_distances_and_no_colour():
    squared = np.random.default_rng().integers(0, 255 * 255 + 1, (2, 3, 4)).astype(np.uint16)
    block = block_of(squared, "squared_distance", "packed")
    assert block.data.dtype == np.uint16 and block.content == "squared_distance"
    assert block.distance.dtype == np.float32
    np.testing.assert_allclose(block.distance, np.sqrt(squared.astype(np.float64)), rtol=1e-6)
    with pytest.raises(ValueError, match="no colour"):
        block.colour


def test_a_manhattan_packed_block_splits_distance_and_colour():
    packed = np.random.default_rng().integers(0, 1 << 16, (2, 3, 4)).astype(np.uint16)
    for content in ("distance_colour", ""):  # "": a server that does not say
        block = block_of(packed, content, "packed")
        np.testing.assert_array_equal(block.distance, packed >> 8)
        np.testing.assert_array_equal(block.colour, packed & 0xFF)


@pytest.mark.parametrize("metric,signed", [("euclidean", False), ("euclidean", True), ("manhattan", True)])
def test_reads_of_a_server_world_of_each_metric_and_sign(server_url, metric, signed):
    cap = 6
    r = httpx.post(f"{server_url}/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8, "max_distance": cap,
                                                    "metric": metric, "signed": signed})
    assert r.status_code == 201, r.text
    with Client(server_url) as client:
        world = client.get_world(r.json()["id"])
        try:
            version = client.edit(world.id, [edits.sphere((7, 8, 9), 3.5, colour=0x1C)])
            solid = client.read_voxels(world.id, min_version=version).data != 0
            field = client.read_field(world.id, min_version=version)
            packed = client.read_field(world.id, format="packed", min_version=version)
        finally:
            client.delete_world(world.id)
    if metric == "euclidean":
        outside, inside = ndimage.distance_transform_edt(~solid), ndimage.distance_transform_edt(solid)
    else:
        outside = ndimage.distance_transform_cdt(~solid, metric="taxicab").astype(np.float64)
        inside = ndimage.distance_transform_cdt(solid, metric="taxicab").astype(np.float64)
    # The sphere lies inside the world: a solid's nearest air voxel is in it.
    expected = np.where(solid, -np.minimum(inside, cap) if signed else 0.0, np.minimum(outside, cap))
    assert field.content == "distance"
    assert field.data.dtype == {"euclidean": np.float32, "manhattan": np.int16}[metric]
    np.testing.assert_allclose(field.distance, expected, rtol=0, atol=1e-5)
    np.testing.assert_allclose(packed.distance, np.abs(expected), rtol=0, atol=1e-5)
    if metric == "manhattan":
        assert packed.content == "distance_colour"
        np.testing.assert_array_equal(packed.colour, np.where(solid, 0x1C, 0))
    else:
        assert packed.content == "squared_distance"
