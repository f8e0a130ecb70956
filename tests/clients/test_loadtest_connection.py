"""The load test's connections (``loadtest.connection.Connection``, aiohttp, and
``loadtest.parsed.ParsedConnection``, httptools): the same answers and errors as
``sdfclient.AsyncClient`` from a real server."""

from __future__ import annotations

import asyncio
import secrets
import sys

import numpy as np
import pytest
from clients_support import CLIENTS, apply_edits, oracle_distance, random_batch

from sdfclient import AsyncClient, Client, InvalidEdit, NotFound, ServerError, edits

sys.path.insert(0, str(CLIENTS))
from loadtest.connection import Connection  # noqa: E402
from loadtest.parsed import ParsedConnection  # noqa: E402

LEAN = pytest.mark.parametrize("Lean", [Connection, ParsedConnection])

SIZE, CAP = (32, 32, 16), 12


# -- against a real server ---------------------------------------------------------------------------


@pytest.fixture
def two_worlds(server_url):
    with Client(server_url) as client:
        ids = [client.create_world(SIZE, chunk_size=16, max_distance=CAP).id for _ in range(2)]
        yield ids
        for world_id in ids:
            client.delete_world(world_id)


@LEAN
def test_same_results_as_async_client(server_url, two_worlds, Lean):
    seed = secrets.randbits(32)
    rng = np.random.default_rng(seed)
    batches = [random_batch(rng, SIZE) for _ in range(5)]
    expected = np.zeros(SIZE[::-1], dtype=np.uint8)
    for batch in batches:
        apply_edits(expected, batch)
    mine_id, httpx_id = two_worlds
    box = ((3, 5, 2), (29, 21, 16))
    points = rng.uniform(0, 15.9, (20, 3))

    async def run():
        async with Lean(server_url) as mine, AsyncClient(server_url) as reference:
            out = {}
            for name, client, world_id in (("lean", mine, mine_id), ("httpx", reference, httpx_id)):
                versions = [await client.edit(world_id, batch) for batch in batches]
                whole = await client.read_field(world_id, min_version=versions[-1])
                part = await client.read_field(world_id, box, format="packed", min_version=versions[-1])
                voxels = await client.read_voxels(world_id)
                hits = await client.query(world_id, points, min_version=versions[-1])
                out[name] = versions, whole, part, voxels, hits
            return out

    out = asyncio.run(run())
    versions, whole, part, voxels, hits = out["lean"]
    assert versions == list(range(1, 6)) == out["httpx"][0], seed
    np.testing.assert_array_equal(whole.distance, oracle_distance(expected, CAP), err_msg=f"seed {seed}")
    np.testing.assert_array_equal(voxels.data, expected, err_msg=f"seed {seed}")
    assert whole.version >= 5 and part.origin == box[0] and part.data.dtype == np.uint16
    np.testing.assert_array_equal(part.data, out["httpx"][2].data, err_msg=f"seed {seed}")
    np.testing.assert_array_equal(part.distance, whole.distance[2:16, 5:21, 3:29])
    np.testing.assert_array_equal(hits.distances, out["httpx"][4].distances)
    np.testing.assert_array_equal(hits.gradients, out["httpx"][4].gradients)


@LEAN
def test_same_errors_as_async_client(server_url, two_worlds, Lean):
    world_id = two_worlds[0]
    outside = np.array([[1, 1, 1, 5], [SIZE[0], 0, 0, 5]])
    calls = [
        lambda c: c.edit("000000000000", [edits.sphere((1, 1, 1), 1)]),
        lambda c: c.read_field("000000000000"),
        lambda c: c.edit(world_id, [edits.sphere((4, 4, 4), 2), edits.voxels(outside)]),
        lambda c: c.read_field(world_id, ((0, 0, 0), (64, 64, 64))),
    ]

    async def caught(client, call) -> ServerError:
        with pytest.raises(ServerError) as info:
            await call(client)
        return info.value

    async def run():
        async with Lean(server_url) as mine, AsyncClient(server_url) as reference:
            pairs = [(await caught(mine, call), await caught(reference, call)) for call in calls]
            after = await mine.read_voxels(world_id)  # the connection still serves after errors
            return pairs, after

    pairs, after = asyncio.run(run())
    for mine, theirs in pairs:
        assert type(mine) is type(theirs)
        assert (mine.status, mine.code, mine.message) == (theirs.status, theirs.code, theirs.message)
    assert isinstance(pairs[0][0], NotFound) and pairs[0][0].status == 404 and pairs[0][0].code == "not_found"
    assert isinstance(pairs[2][0], InvalidEdit) and pairs[2][0].status == 422
    assert 400 <= pairs[3][0].status < 500
    assert after.version == 0 and not after.data.any()  # the refused batch changed nothing
