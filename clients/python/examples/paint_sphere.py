"""Paint a sphere into a new world and read its distance field back (read-your-writes).

    python clients/python/examples/paint_sphere.py http://127.0.0.1:8000
"""

import os
import sys

import _path  # noqa: F401 - run from a checkout without installing

from sdfclient import Client, edits

url = sys.argv[1] if len(sys.argv) > 1 else "http://127.0.0.1:8000"
with Client(url, api_key=os.environ.get("SDFSERVER_API_KEY")) as client:
    world = client.create_world((32, 32, 32), chunk_size=16, max_distance=32)
    try:
        version = client.edit(world.id, [edits.sphere((16, 16, 16), 5, colour=0xE0)])
        field = client.read_field(world.id, min_version=version)  # waits until the field has the sphere
        d = field.distance  # (z, y, x)
        print(f"world {world.id}: version {field.version}, field {field.shape} {d.dtype}")
        print(f"distance at the centre (16,16,16): {d[16, 16, 16]}")
        print(f"distance at (16,16,24), 3 voxels off the surface: {d[16, 16, 24]}")
        print(f"distance at the corner (0,0,0): {d[0, 0, 0]}")
        print(f"solid voxels: {int((d == 0).sum())}")
    finally:
        client.delete_world(world.id)
