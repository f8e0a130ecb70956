"""sdfclient: the Python client of sdfserver.

    from sdfclient import Client, edits
    with Client("http://127.0.0.1:8000") as client:
        world = client.create_world((64, 64, 64))
        version = client.edit(world.id, [edits.sphere((32, 32, 32), 6)])
        field = client.read_field(world.id, min_version=version)

``AsyncClient`` has the same methods, awaitable, and ``stream(world_id)``
for the WebSocket stream (``sdfclient.stream.Stream``). Every failure raises
an ``sdfclient.errors.SdfClientError``.
"""

from sdfclient import edits
from sdfclient.client import AsyncClient, Client
from sdfclient.errors import (
    DeviceMemoryExceeded, InternalServerError, InvalidEdit, InvalidInput, NotFound, NotReady, ProtocolError,
    SdfClientError, ServerError, StreamClosed, Timeout, TooLarge, TransportError,
    VersionNotReached,
)
from sdfclient.models import Block, ChunkUpdate, Focus, QueryResult, StreamMessage, WorldInfo
from sdfclient.stream import Stream

__all__ = [
    "AsyncClient", "Block", "ChunkUpdate", "Client", "DeviceMemoryExceeded", "Focus", "InternalServerError",
    "InvalidEdit", "InvalidInput", "NotFound", "NotReady", "ProtocolError", "QueryResult", "SdfClientError",
    "ServerError", "Stream", "StreamClosed", "StreamMessage", "Timeout", "TooLarge", "TransportError",
    "VersionNotReached", "WorldInfo", "edits",
]
