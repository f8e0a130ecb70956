"""Build a floor and ask the server how far points above it are, and which way is away from it.

    python clients/examples/query_points.py http://127.0.0.1:8000
"""

import os
import sys

import numpy as np

import _path  # noqa: F401 - run from a checkout without installing

from sdfclient import Client, edits

url = sys.argv[1] if len(sys.argv) > 1 else "http://127.0.0.1:8000"
with Client(url, api_key=os.environ.get("SDFSERVER_API_KEY")) as client:
    world = client.create_world((32, 32, 32), chunk_size=16, max_distance=16)
    try:
        # A floor: the layer y = 0 (boxes are half-open).
        version = client.edit(world.id, [edits.box((0, 0, 0), (32, 1, 32), colour=0x1C)])
        heights = np.arange(0, 6)
        points = np.stack([np.full(6, 10), heights, np.full(6, 12)], axis=1)  # x, y, z
        result = client.query(world.id, points, min_version=version)
        for p, dist, grad in zip(points, result.distances, result.gradients):
            print(f"point {p.tolist()}: distance {float(dist):g}, gradient {np.round(grad, 3).tolist()}")
    finally:
        client.delete_world(world.id)
