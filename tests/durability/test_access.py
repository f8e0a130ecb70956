"""API keys through a real server: every route and the stream refuse a missing or wrong key and
another tenant's world (404, word for word as a missing world); an admin key sees everything;
worlds per key and the per-key rate limit; no keys means loopback only."""

import subprocess
import sys

import httpx
import pytest
from websockets.sync.client import connect

from sdfserver import wire

from server_process import ROOT, checkout_env

ALICE, BOB, ROOT_KEY, CAROL = "alice-token-0123456789", "bob-token-0123456789ab", "root-token-0123456789", \
    "carol-token-0123456789"


@pytest.fixture
def server(start_server, tmp_path):
    key_file = tmp_path / "keys"
    key_file.write_text(f"# tenants\nbob {BOB}\nroot {ROOT_KEY} admin\ncarol {CAROL}\n")
    return start_server("--api-keys", f"alice:{ALICE}", "--api-key-file", str(key_file),
                        "--max-worlds-per-key", "2", "--rate-limit-per-s", "1", "--rate-limit-burst", "80")


@pytest.fixture
def client():
    made = []

    def make(server, token):
        made.append(httpx.Client(base_url=server.url, timeout=30,
                                 headers={"authorization": f"Bearer {token}"} if token else {}))
        return made[-1]

    yield make
    for c in made:
        c.close()


def routes(world_id):
    edit = {"edits": [{"op": "box", "min": [0, 0, 0], "max": [2, 2, 2], "colour": 7}]}
    return [
        ("GET", "/v1/worlds", None), ("POST", "/v1/worlds", {"size": [8, 8, 8], "chunk_size": 8}),
        ("GET", f"/v1/worlds/{world_id}", None), ("PATCH", f"/v1/worlds/{world_id}", {"max_distance": 5}),
        ("POST", f"/v1/worlds/{world_id}/edits", edit), ("GET", f"/v1/worlds/{world_id}/field", None),
        ("GET", f"/v1/worlds/{world_id}/voxels", None),
        ("POST", f"/v1/worlds/{world_id}/query", {"points": [[1, 1, 1]]}),
        ("DELETE", f"/v1/worlds/{world_id}", None),
    ]


def test_keys_tenants_and_admin(server, client):
    alice, bob, admin = client(server, ALICE), client(server, BOB), client(server, ROOT_KEY)
    r = alice.post("/v1/worlds", json={"size": [8, 8, 8], "chunk_size": 8})
    assert r.status_code == 201, r.text
    world = r.json()["id"]
    version = alice.get(f"/v1/worlds/{world}").json()["version"]

    for token in (None, "wrong-token-0123456789", ALICE[:-1]):
        anyone = client(server, token)
        for method, path, body in routes(world):
            r = anyone.request(method, path, json=body)
            assert r.status_code == 401, (method, path, r.text)
            assert r.json()["error"]["code"] == "unauthorized"
            assert r.headers["www-authenticate"].startswith("Bearer")

    missing = "doesNotExist"
    for method, path, body in routes(world)[2:]:
        theirs = bob.request(method, path, json=body)
        nobody = bob.request(method, path.replace(world, missing), json=body)
        assert theirs.status_code == 404 == nobody.status_code, (method, path, theirs.text)
        assert theirs.json()["error"]["message"].replace(world, missing) == nobody.json()["error"]["message"]
    assert alice.get(f"/v1/worlds/{world}").json()["version"] == version  # bob changed nothing

    bobs = bob.post("/v1/worlds", json={"size": [8, 8, 8], "chunk_size": 8}).json()["id"]
    assert [w["id"] for w in alice.get("/v1/worlds").json()["worlds"]] == [world]
    assert [w["id"] for w in bob.get("/v1/worlds").json()["worlds"]] == [bobs]
    assert {w["id"] for w in admin.get("/v1/worlds").json()["worlds"]} == {world, bobs}
    r = admin.post(f"/v1/worlds/{world}/edits", json={"edits": [{"op": "box", "min": [0, 0, 0],
                                                                   "max": [1, 1, 1], "colour": 3}]})
    assert r.status_code == 200 and r.json()["version"] == version + 1

    assert alice.post("/v1/worlds", json={"size": [8, 8, 8], "chunk_size": 8}).status_code == 201
    r = alice.post("/v1/worlds", json={"size": [8, 8, 8], "chunk_size": 8})
    assert r.status_code == 413 and "owns 2 worlds" in r.text

    # The stream: a missing key, a wrong key, another tenant's world, then the owner.
    ws = server.url.replace("http://", "ws://") + f"/v1/worlds/{world}/stream"
    for url, headers, code in ((ws, {}, 4401), (ws + "?access_token=nope-nope-nope-nope", {}, 4401),
                               (ws, {"authorization": f"Bearer {BOB}"}, 4404)):
        with connect(url, additional_headers=headers) as sock:
            with pytest.raises(Exception) as info:
                sock.recv(timeout=10)
            assert getattr(info.value, "rcvd", None) is not None and info.value.rcvd.code == code
    with connect(ws + f"?access_token={ALICE}") as sock:
        sock.send(wire.encode({"type": "ping", "id": 1}))
        assert wire.decode(sock.recv(timeout=10)) == {"type": "pong", "id": 1}


def test_rate_limit_per_key(server, client):
    carol, alice = client(server, CAROL), client(server, ALICE)
    statuses = [carol.get("/v1/worlds").status_code for _ in range(100)]
    assert statuses[:75].count(200) == 75 and 429 in statuses
    r = carol.get("/v1/worlds")
    assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1
    assert r.json()["error"]["code"] == "rate_limited"
    assert alice.get("/v1/worlds").status_code == 200  # another key has its own bucket


def test_no_keys_means_loopback_only(tmp_path):
    result = subprocess.run([sys.executable, "-m", "sdfserver", "serve", "--host", "0.0.0.0", "--port", "1",
                             "--data-dir", str(tmp_path / "d")], cwd=ROOT, capture_output=True, text=True,
                            timeout=60, env={"PYTHONPATH": checkout_env()["PYTHONPATH"], "PATH": "/usr/bin:/bin"})
    assert result.returncode == 2
    assert "refusing to listen on 0.0.0.0 with no API keys" in result.stderr
