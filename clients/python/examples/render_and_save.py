"""Paint a small scene, save a rendered PNG and a MagicaVoxel .vox of it, and load the .vox back
as a second world.

    python clients/python/examples/render_and_save.py http://127.0.0.1:8000 [output directory, made if missing]

Against a server with API keys, set SDFSERVER_API_KEY.
"""

import os
import sys
from pathlib import Path

import _path  # noqa: F401 - run from a checkout without installing

from sdfclient import Camera, Client, edits

url = sys.argv[1] if len(sys.argv) > 1 else "http://127.0.0.1:8000"
out = Path(sys.argv[2] if len(sys.argv) > 2 else ".")
out.mkdir(parents=True, exist_ok=True)
with Client(url, api_key=os.environ.get("SDFSERVER_API_KEY")) as client:
    world = client.create_world((64, 32, 64), chunk_size=16, max_distance=32)
    copy = None
    try:
        version = client.edit(world.id, [
            edits.box((0, 0, 0), (64, 2, 64), colour=0x92),       # a grey floor
            edits.sphere((32, 12, 32), 9, colour=0xE0),           # a red ball on it
            edits.box((46, 2, 12), (52, 22, 18), colour=0x1C),    # a green pillar
        ])
        client.read_field(world.id, min_version=version)          # the frame shows this version
        camera = Camera.look_at((80, 40, 90), (32, 8, 32), width=320, height=200)
        frame = client.render(world.id, camera, format="png", ambient_occlusion=True, shadows=True)
        (out / "scene.png").write_bytes(frame.data)
        print(f"scene.png: {frame.width}x{frame.height}, field version {frame.field_version}, "
              f"{len(frame.data)} bytes, rendered in {frame.render_ms:.2f} ms")

        exported = client.export_world(world.id, "vox", path=out / "scene.vox")
        print(f"scene.vox: version {exported.version}, {len(exported.data)} bytes")
        copy = client.import_world(out / "scene.vox", chunk_size=16)
        same = (client.read_voxels(copy.id).data == client.read_voxels(world.id).data).all()
        print(f"imported as world {copy.id}: size {copy.size}, voxels equal: {bool(same)}")
    finally:
        client.delete_world(world.id)
        if copy is not None:
            client.delete_world(copy.id)
