"""Build a floor and ask the server how far points above it are, and which way is away from it.

    python clients/python/examples/query_points.py http://127.0.0.1:8000
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
        # x, y, z at voxel centres (voxel_size 1, origin 0): each answers its voxel's distance
        points = np.stack([np.full(6, 10.5), heights + 0.5, np.full(6, 12.5)], axis=1)
        result = client.query(world.id, points, min_version=version)
        for p, dist, grad in zip(points, result.distances, result.gradients):
            print(f"point {p.tolist()}: distance {float(dist):g}, gradient {np.round(grad, 3).tolist()}")
        # A sphere of radius 1 three voxels above the floor (the field counts from voxel centres),
        # and a ray cast straight down at the floor.
        spheres = client.query_spheres(world.id, [[10.5, 3.5, 12.5, 1.0]])
        print(f"sphere clearance {float(spheres.clearances[0]):g}, way out {spheres.directions[0].tolist()}")
        rays = client.query_rays(world.id, [[10.5, 5.5, 12.5, 0, -1, 0, 20]])
        print(f"ray down: hit {bool(rays.hits[0])} at {float(rays.distances[0]):g}, voxel {rays.voxels[0].tolist()}, "
              f"normal {rays.normals[0].tolist()}")
    finally:
        client.delete_world(world.id)
