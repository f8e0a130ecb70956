"""The client against a server with API keys: bearer tokens on HTTP and the stream, tenants that
cannot see each other's worlds (NotFound, as for a missing world), an admin that sees all,
Unauthorized for a wrong or missing key, RateLimited with its Retry-After, and the load test
with a key."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from clients_support import CLIENTS, ROOT, env_with_paths, oracle_distance, random_batch, serve

from sdfclient import AsyncClient, Camera, Client, NotFound, RateLimited, Unauthorized, edits

ALICE, BOB, ADMIN = "alice-token-0123456789", "bob-token-0123456789ab", "admin-token-0123456789"
LOADER, FLOOD = "loader-token-0123456789", "flood-token-0123456789"
BURST = 60  # every key's bucket: the tests of one key stay under it, except the flood test
SIZE, CAP = (32, 32, 16), 12


@pytest.fixture(scope="module")
def url(tmp_path_factory):
    keys = f"alice:{ALICE},bob:{BOB},root:{ADMIN}:admin,loader:{LOADER},flood:{FLOOD}"
    with serve(tmp_path_factory.mktemp("keyed"), "--api-keys", keys, "--rate-limit-per-s", "2",
               "--rate-limit-burst", str(BURST)) as server_url:
        yield server_url


@pytest.fixture(scope="module")
def worlds(url):
    """A world of alice's and one of bob's, each with random edits; their voxels after them."""
    rng = np.random.default_rng()
    made = {}
    for name, key in (("alice", ALICE), ("bob", BOB)):
        with Client(url, api_key=key) as client:
            info = client.create_world(SIZE, chunk_size=16, max_distance=CAP)
            for _ in range(3):
                version = client.edit(info.id, random_batch(rng, SIZE))
            made[name] = (info.id, client.read_voxels(info.id, min_version=version).data)
    return made


def test_tenants_see_only_their_own_worlds(url, worlds):
    a_id, a_voxels = worlds["alice"]
    b_id, b_voxels = worlds["bob"]
    assert not np.array_equal(a_voxels, b_voxels)
    with Client(url, api_key=ALICE) as alice, Client(url, api_key=ADMIN) as admin:
        assert {w.id for w in alice.list_worlds()} == {a_id}
        np.testing.assert_array_equal(alice.read_voxels(a_id).data, a_voxels)
        field = alice.read_field(a_id)
        np.testing.assert_array_equal(field.distance, oracle_distance(a_voxels, CAP))

        # Bob's world is a 404 to alice on every route, word for word as a world that does not exist.
        with pytest.raises(NotFound) as missing:
            alice.get_world("NoSuchWorld")
        camera = Camera.look_at((40, 40, 40), (16, 16, 8), width=32, height=24)
        refusals = [lambda: alice.get_world(b_id), lambda: alice.read_voxels(b_id),
                    lambda: alice.read_field(b_id), lambda: alice.query(b_id, [[1, 1, 1]]),
                    lambda: alice.edit(b_id, [edits.box((0, 0, 0), (4, 4, 4), 9)]),
                    lambda: alice.update_world(b_id, max_distance=3), lambda: alice.export_world(b_id, "npy"),
                    lambda: alice.render(b_id, camera), lambda: alice.delete_world(b_id)]
        for refused in refusals:
            with pytest.raises(NotFound) as caught:
                refused()
            assert caught.value.status == 404 and caught.value.code == "not_found"
            assert caught.value.message == missing.value.message.replace("NoSuchWorld", b_id)

        # The admin sees both, unchanged by alice's attempts.
        assert {a_id, b_id} <= {w.id for w in admin.list_worlds()}
        b_world = admin.get_world(b_id)
        assert b_world.max_distance == CAP and b_world.version == 3
        np.testing.assert_array_equal(admin.read_voxels(b_id).data, b_voxels)


def test_wrong_or_missing_key_is_unauthorized(url, worlds):
    a_id, _ = worlds["alice"]
    for key in ("not-a-key-0123456789abc", None):
        with Client(url, api_key=key) as client:
            for call in (client.list_worlds, lambda: client.get_world(a_id),
                         lambda: client.create_world(SIZE, chunk_size=16)):
                with pytest.raises(Unauthorized) as caught:
                    call()
                assert caught.value.status == 401 and caught.value.code == "unauthorized"
    with pytest.raises(ValueError):
        Client(url, api_key="two words")

    async def run():
        async with AsyncClient(url, api_key="not-a-key-0123456789abc") as client:
            with pytest.raises(Unauthorized):
                await client.read_voxels(a_id)
    asyncio.run(run())
    with Client(url, api_key=ALICE) as alice:
        assert alice.get_world(a_id).version == 3  # nothing changed


def test_the_load_tests_connection_sends_the_key(url, worlds):
    sys.path.insert(0, str(CLIENTS))
    from loadtest.connection import Connection

    a_id, a_voxels = worlds["alice"]

    async def run():
        async with Connection(url, api_key=ALICE) as alice:
            voxels = (await alice.read_voxels(a_id)).data
            field = await alice.read_field(a_id)
        refused = []
        for key in (BOB, "not-a-key-0123456789abc", None):
            async with Connection(url, api_key=key) as other:
                try:
                    await other.edit(a_id, [edits.box((0, 0, 0), (8, 8, 8), 0x11)])
                except (NotFound, Unauthorized) as exc:
                    refused.append(exc)
        return voxels, field, refused

    voxels, field, refused = asyncio.run(run())
    np.testing.assert_array_equal(voxels, a_voxels)
    np.testing.assert_array_equal(field.distance, oracle_distance(a_voxels, CAP))
    assert [type(e) for e in refused] == [NotFound, Unauthorized, Unauthorized]
    assert [e.status for e in refused] == [404, 401, 401]


def test_stream_carries_the_key(url, worlds):
    a_id, a_voxels = worlds["alice"]

    async def run():
        async with AsyncClient(url, api_key=ALICE) as alice:
            async with alice.stream(a_id) as stream:
                await stream.subscribe(((0, 0, 0), SIZE))
                version = await stream.edit([edits.box((0, 0, 0), (3, 3, 3), 0x42)])
            voxels = (await alice.read_voxels(a_id, min_version=version)).data
        refused = {}
        for name, key in (("bob", BOB), ("wrong", "not-a-key-0123456789abc"), ("none", None)):
            async with AsyncClient(url, api_key=key) as other:
                try:
                    async with other.stream(a_id) as stream:
                        await stream.edit([edits.box((0, 0, 0), (8, 8, 8), 0x11)])
                except (NotFound, Unauthorized) as exc:
                    refused[name] = exc
        async with AsyncClient(url, api_key=ALICE) as alice:
            after = (await alice.read_voxels(a_id)).data
        return version, voxels, refused, after

    version, voxels, refused, after = asyncio.run(run())
    assert version == 4
    expected = a_voxels.copy()
    expected[:3, :3, :3] = 0x42
    np.testing.assert_array_equal(voxels, expected)
    assert isinstance(refused["bob"], NotFound)
    assert isinstance(refused["wrong"], Unauthorized) and isinstance(refused["none"], Unauthorized)
    np.testing.assert_array_equal(after, expected)  # the refused streams changed nothing


def test_imports_belong_to_the_importer(url, worlds):
    a_id, _ = worlds["alice"]
    with Client(url, api_key=ALICE) as alice, Client(url, api_key=BOB) as bob:
        exported = alice.export_world(a_id, "snapshot")
        copy = bob.import_world(exported.data, "snapshot")
        try:
            assert copy.version == 1 and copy.size == SIZE and copy.max_distance == CAP
            np.testing.assert_array_equal(bob.read_voxels(copy.id).data, alice.read_voxels(a_id).data)
            with pytest.raises(NotFound):
                alice.get_world(copy.id)
            with pytest.raises(NotFound):
                alice.export_world(copy.id)
        finally:
            bob.delete_world(copy.id)
    with Client(url, api_key="not-a-key-0123456789abc") as stranger, pytest.raises(Unauthorized):
        stranger.import_world(exported.data, "snapshot")


def test_rate_limited_carries_retry_after(url):
    with Client(url, api_key=FLOOD, retries=0) as client:
        served = 0
        with pytest.raises(RateLimited) as caught:
            for _ in range(4 * BURST):
                client.list_worlds()
                served += 1
    assert BURST - 5 <= served <= 2 * BURST  # the burst went through first
    assert caught.value.status == 429 and caught.value.code == "rate_limited"
    assert caught.value.retry_after_s is not None and 1 <= caught.value.retry_after_s <= 5


def test_a_refused_rate_is_waited_out_and_the_request_sent_again(url):
    with Client(url, api_key=FLOOD, retries=0) as drain:  # the key's bucket empty, whatever ran before
        with contextlib.suppress(RateLimited):
            for _ in range(4 * BURST):
                drain.list_worlds()
    with Client(url, api_key=FLOOD) as client:  # retries by default: every call answered
        started = time.monotonic()
        for _ in range(3):
            assert isinstance(client.list_worlds(), list)
        assert time.monotonic() - started >= 0.9  # at least one Retry-After (1 s) waited out


def _loadtest(url: str, tmp_path, key_env: str | None, *args: str) -> subprocess.CompletedProcess:
    env = env_with_paths()
    if key_env is not None:
        env["SDFSERVER_API_KEY"] = key_env
    return subprocess.run([sys.executable, str(CLIENTS / "loadtest"), "--url", url, "--quiet",
                           "--json", str(tmp_path / "out.json"), *args],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)


def test_loadtest_with_a_key(url, tmp_path):
    args = ("--clients", "2", "--requests", "24", "--duration", "20", "--size", "32", "32", "32")
    with Client(url, api_key=ADMIN) as admin:
        before = {w.id for w in admin.list_worlds()}
    proc = _loadtest(url, tmp_path, LOADER, *args)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    text = (tmp_path / "out.json").read_text()
    result = json.loads(text)
    assert result["errors"]["count"] == 0 and result["edits"]["count"] >= 12
    assert result["config"]["api_key"] == "(set)"
    assert LOADER not in text + proc.stdout + proc.stderr  # the key is never reported
    with Client(url, api_key=ADMIN) as admin:  # it deleted its world again
        assert {w.id for w in admin.list_worlds()} == before

    os.remove(tmp_path / "out.json")
    proc = _loadtest(url, tmp_path, None, "--api-key", "not-a-key-0123456789abc", *args)
    assert proc.returncode == 2 and "401" in proc.stderr and "unknown API key" in proc.stderr
    assert not (tmp_path / "out.json").exists()
