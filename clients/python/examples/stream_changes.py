"""Subscribe to a world over the WebSocket stream, paint through it, and print the chunks that change.

    python clients/python/examples/stream_changes.py http://127.0.0.1:8000
"""

import asyncio
import os
import sys

import _path  # noqa: F401 - run from a checkout without installing

from sdfclient import AsyncClient, edits


async def main(url: str) -> None:
    async with AsyncClient(url, api_key=os.environ.get("SDFSERVER_API_KEY")) as client:
        world = await client.create_world((64, 32, 32), chunk_size=16, max_distance=8)
        try:
            async with client.stream(world.id) as stream:
                await stream.subscribe(((0, 0, 0), (64, 32, 32)), format="packed")
                first = await stream.recv()  # the subscribed region as it is now
                print(f"subscribed: {len(first.chunks)} chunks at version {first.version}")
                version = await stream.edit([edits.sphere((8, 8, 8), 3, colour=0xFF)])
                print(f"edit acknowledged: version {version}")
                async for message in stream:
                    if message.type != "chunks" or message.version < version:
                        continue
                    origins = sorted(c.origin for c in message.chunks)
                    print(f"version {message.version}: {len(origins)} changed chunks at {origins}")
                    break
        finally:
            await client.delete_world(world.id)


asyncio.run(main(sys.argv[1] if len(sys.argv) > 1 else "http://127.0.0.1:8000"))
