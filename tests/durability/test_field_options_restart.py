"""A restart keeps each world's metric, sign, voxel size and origin, and its field reads back the
same (dtype, content and values), dense and sparse; a PATCHed metric and sign are kept too."""

import numpy as np

from sdfserver import wire

OPTIONS = ("metric", "signed", "voxel_size", "origin", "storage")


def read_field(http, world_id, version):
    r = http.get(f"/v1/worlds/{world_id}/field", params={"min_version": version},
                 headers={"accept": wire.CONTENT_TYPE})
    assert r.status_code == 200, r.text
    msg = wire.decode(r.content)
    return msg["dtype"], msg["content"], np.frombuffer(msg["data"], msg["dtype"]).reshape(msg["shape"])


def test_a_restart_keeps_the_field_options(start_server, tmp_path):
    server = start_server()
    http = server.http
    worlds = {}
    for body in ({"metric": "euclidean", "signed": True, "voxel_size": 0.5, "origin": [1.5, -2.0, 3e3]},
                 {"metric": "manhattan", "signed": True, "storage": "sparse", "voxel_size": 4.0},
                 {"metric": "euclidean", "storage": "sparse", "origin": [-7.0, 0.0, 0.25]},
                 {"voxel_size": 0.125}):  # PATCHed below to Euclidean, signed
        r = http.post("/v1/worlds", json={"size": [16, 16, 24], "chunk_size": 8, "max_distance": 6, **body})
        assert r.status_code == 201, r.text
        world = r.json()["id"]
        r = http.post(f"/v1/worlds/{world}/edits", json={"edits": [
            {"op": "sphere", "center": [8, 7, 11], "radius": 4.5, "colour": 12},
            {"op": "box", "min": [0, 0, 0], "max": [16, 2, 24], "colour": 200}]})
        assert r.status_code == 200, r.text
        worlds[world] = r.json()["version"]
    r = http.patch(f"/v1/worlds/{world}", json={"metric": "euclidean", "signed": True})
    assert r.status_code == 200, r.text
    described = {w: {k: http.get(f"/v1/worlds/{w}").json()[k] for k in OPTIONS} for w in worlds}
    assert described[world]["metric"] == "euclidean" and described[world]["signed"] is True
    fields = {w: read_field(http, w, v) for w, v in worlds.items()}

    server.stop()
    http = start_server(data_dir=tmp_path / "data").http
    for w, version in worlds.items():
        assert {k: http.get(f"/v1/worlds/{w}").json()[k] for k in OPTIONS} == described[w]
        dtype, content, field = read_field(http, w, version)
        assert (dtype, content) == fields[w][:2]
        np.testing.assert_array_equal(field, fields[w][2])
