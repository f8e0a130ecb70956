"""A world's palette through a real server: PATCH changes it and the next frame shows it; bad
palettes are refused naming the field; snapshot and .vox exports carry it and import back with
it; a restart keeps it, for the PATCHed world and the imported ones."""

import numpy as np

from durable_server import read_voxels

OCTET = {"content-type": "application/octet-stream"}
RED = 0b111_000_00  # RGB332 red: the default palette draws it (255, 0, 0)
CAMERA = {"position": [8.5, 30.0, 8.5], "target": [8.5, 0.0, 8.51], "fov_y_deg": 20.0, "width": 8,
          "height": 8, "format": "rgba"}


def centre_colour(http, world_id):
    r = http.post(f"/v1/worlds/{world_id}/render", json=CAMERA)
    assert r.status_code == 200, r.text
    return tuple(np.frombuffer(r.content, np.uint8).reshape(8, 8, 4)[4, 4, :3].tolist())


def make_floor(http, **config):
    r = http.post("/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8, **config})
    assert r.status_code == 201, r.text
    world = r.json()["id"]
    r = http.post(f"/v1/worlds/{world}/edits",
                  json={"edits": [{"op": "box", "min": [0, 0, 0], "max": [16, 2, 16], "colour": RED}]})
    assert r.status_code == 200, r.text
    return world


def test_bad_palettes_are_refused_naming_the_field(start_server):
    http = start_server().http
    world = make_floor(http)
    for bad in ([[0, 0, 0]] * 254, [[0, 0, 256]] * 255, [[0, 0]] * 255, "red", [[0, 0, -1]] * 255):
        for r in (http.post("/v1/worlds", json={"size": [16, 16, 16], "chunk_size": 8, "palette": bad}),
                  http.patch(f"/v1/worlds/{world}", json={"palette": bad})):
            assert r.status_code == 422, (bad, r.text)
            assert "palette" in r.text, r.text
    assert http.get(f"/v1/worlds/{world}").json().get("palette") is None
    assert centre_colour(http, world) == (255, 0, 0)


def test_palette_patch_export_import_and_restart(start_server, tmp_path):
    server = start_server()
    http = server.http
    rng = np.random.default_rng()
    world = make_floor(http, metric="euclidean")
    assert centre_colour(http, world) == (255, 0, 0)  # no palette: RGB332
    palette = rng.integers(0, 256, (255, 3)).tolist()
    palette[RED - 1] = [20, 140, 230]
    r = http.patch(f"/v1/worlds/{world}", json={"palette": palette})
    assert r.status_code == 200, r.text
    assert http.get(f"/v1/worlds/{world}").json()["palette"] == palette
    assert centre_colour(http, world) == (20, 140, 230)  # the floor's top: full brightness

    imported = {}
    for fmt in ("snapshot", "vox"):
        body = http.get(f"/v1/worlds/{world}/export", params={"format": fmt}).content
        r = http.post("/v1/worlds/import", params={"format": fmt, "chunk_size": 8}, content=body, headers=OCTET)
        assert r.status_code == 201, r.text
        assert r.json()["palette"] == palette, fmt
        imported[fmt] = r.json()["id"]
        np.testing.assert_array_equal(read_voxels(http, imported[fmt])[1], read_voxels(http, world)[1])
        assert centre_colour(http, imported[fmt]) == (20, 140, 230)
    assert http.get(f"/v1/worlds/{imported['snapshot']}").json()["metric"] == "euclidean"

    server.stop()
    http = start_server(data_dir=tmp_path / "data").http
    for world_id in (world, *imported.values()):
        assert http.get(f"/v1/worlds/{world_id}").json()["palette"] == palette
        assert centre_colour(http, world_id) == (20, 140, 230)
