"""sdfclient: the Python client of sdfserver.

    from sdfclient import Camera, Client, edits
    with Client("http://127.0.0.1:8000", api_key=token) as client:   # api_key: None on an open server
        world = client.create_world((64, 64, 64))
        version = client.edit(world.id, [edits.sphere((32, 32, 32), 6)])
        field = client.read_field(world.id, min_version=version)
        frame = client.render(world.id, Camera.look_at((90, 70, 90), (32, 32, 32)))
        world_file = client.export_world(world.id, "snapshot")

``AsyncClient`` has the same methods, awaitable, and ``stream(world_id)``
for the WebSocket stream (``sdfclient.stream.Stream``). Every failure raises
an ``sdfclient.errors.SdfClientError``.

A distribution of its own (``pip install ./clients/python``): it needs httpx,
websockets, msgpack and NumPy, and carries the server's wire module as a copy.
"""

from sdfclient import edits
from sdfclient._version import __version__
from sdfclient.client import AsyncClient, Client
from sdfclient.errors import (
    DeviceMemoryExceeded, InternalServerError, InvalidEdit, InvalidInput, NotFound, NotReady, ProtocolError,
    RateLimited, SdfClientError, ServerError, StreamClosed, Timeout, TooLarge, TransportError, Unauthorized,
    VersionNotReached, WritesDisabled,
)
from sdfclient.models import (
    Block, Camera, ChunkUpdate, Exported, Focus, Frame, Pick, QueryResult, RayResult, SphereResult, StreamMessage,
    WorldInfo,
)
from sdfclient.stream import Stream

__all__ = [
    "AsyncClient", "Block", "Camera", "ChunkUpdate", "Client", "DeviceMemoryExceeded", "Exported", "Focus",
    "Frame", "InternalServerError", "InvalidEdit", "InvalidInput", "NotFound", "NotReady", "Pick",
    "ProtocolError", "QueryResult", "RateLimited", "RayResult", "SdfClientError", "ServerError", "SphereResult",
    "Stream", "StreamClosed", "StreamMessage", "Timeout", "TooLarge", "TransportError", "Unauthorized",
    "VersionNotReached", "WorldInfo", "WritesDisabled", "__version__", "edits",
]
