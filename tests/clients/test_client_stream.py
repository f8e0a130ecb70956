"""The WebSocket stream against a real server: acknowledgements, changed chunks, refusals."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from clients_support import oracle_distance

from sdfclient import AsyncClient, InvalidEdit, NotFound, edits
from sdfclient.stream import Stream

SIZE = (64, 32, 32)
CAP = 8


async def _first_chunks(stream: Stream, version: int, timeout: float = 30.0):
    async def wait():
        async for message in stream:
            if message.type == "chunks" and message.version is not None and message.version >= version:
                return message
        raise AssertionError("stream ended before the chunks arrived")

    return await asyncio.wait_for(wait(), timeout)


def test_stream_acks_edits_and_sends_the_changed_chunks(server_url):
    async def run():
        async with AsyncClient(server_url) as client:
            info = await client.create_world(SIZE, chunk_size=16, max_distance=CAP)
            try:
                async with client.stream(info.id) as stream:
                    subscribed = await stream.subscribe(((0, 0, 0), (60, 30, 30)), format="distance")
                    snapshot = await _first_chunks(stream, 0)
                    version = await stream.edit([edits.sphere((6, 6, 6), 2, colour=200)])
                    message = await _first_chunks(stream, version)
                    field = await client.read_field(info.id, min_version=version)
                    voxels = await client.read_voxels(info.id)
                    return subscribed, snapshot, version, message, field.distance, voxels.data
            finally:
                await client.delete_world(info.id)

    subscribed, snapshot, version, message, field, voxels = asyncio.run(run())
    assert subscribed.raw["min"] == [0, 0, 0] and subscribed.raw["max"] == list(SIZE)  # widened to chunks
    assert snapshot.version == 0 and len(snapshot.chunks) == 4 * 2 * 2
    assert all((c.data == CAP).all() for c in snapshot.chunks)
    assert version == 1
    np.testing.assert_array_equal(field, oracle_distance(voxels, CAP))
    origins = sorted(c.origin for c in message.chunks)
    # The sphere and its cap reach x < 16 + 8 only: the chunks at x = 32, 48 are untouched.
    assert (0, 0, 0) in origins and all(o[0] < 32 for o in origins)
    for chunk in message.chunks:
        x, y, z = chunk.origin
        nz, ny, nx = chunk.data.shape
        np.testing.assert_array_equal(chunk.data, field[z:z + nz, y:y + ny, x:x + nx])


def test_stream_refusals(server_url):
    async def run():
        async with AsyncClient(server_url) as client:
            with pytest.raises(NotFound):
                async with client.stream("no-such-world") as stream:
                    await stream.recv()
            info = await client.create_world((32, 32, 32), chunk_size=16, max_distance=CAP)
            try:
                async with client.stream(info.id) as stream:
                    with pytest.raises(InvalidEdit):
                        await stream.edit([edits.voxels(np.array([[40, 0, 0, 1]]))])
                    assert await stream.edit([edits.box((0, 0, 0), (2, 2, 2), 1)]) == 1
            finally:
                await client.delete_world(info.id)

    asyncio.run(run())
