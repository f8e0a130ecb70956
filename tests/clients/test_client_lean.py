"""sdfclient.lean.LeanConnection: the same answers and errors as AsyncClient from a real server, and
its hand-written HTTP/1.1 against a scripted raw-socket server (exact request bytes, connection:
close, a server that closes while idle, chunked and close-delimited bodies, timeouts, broken and
unreadable answers)."""

from __future__ import annotations

import asyncio
import secrets

import numpy as np
import pytest
from clients_support import apply_edits, free_port, oracle_distance, random_batch

from sdfclient import (
    AsyncClient, Client, InvalidEdit, NotFound, ProtocolError, RateLimited, ServerError, Timeout, TransportError,
    edits, lean,
)
from sdfclient.edits import normalize
from sdfclient.lean import LeanConnection
from sdfserver import wire

SIZE, CAP = (32, 32, 16), 12


# -- against a real server ---------------------------------------------------------------------------


@pytest.fixture
def two_worlds(server_url):
    with Client(server_url) as client:
        ids = [client.create_world(SIZE, chunk_size=16, max_distance=CAP).id for _ in range(2)]
        yield ids
        for world_id in ids:
            client.delete_world(world_id)


def test_same_results_as_async_client(server_url, two_worlds):
    seed = secrets.randbits(32)
    rng = np.random.default_rng(seed)
    batches = [random_batch(rng, SIZE) for _ in range(5)]
    expected = np.zeros(SIZE[::-1], dtype=np.uint8)
    for batch in batches:
        apply_edits(expected, batch)
    lean_id, httpx_id = two_worlds
    box = ((3, 5, 2), (29, 21, 16))
    points = rng.uniform(0, 15.9, (20, 3))

    async def run():
        async with LeanConnection(server_url) as lean, AsyncClient(server_url) as reference:
            out = {}
            for name, client, world_id in (("lean", lean, lean_id), ("httpx", reference, httpx_id)):
                versions = [await client.edit(world_id, batch) for batch in batches]
                whole = await client.read_field(world_id, min_version=versions[-1])
                part = await client.read_field(world_id, box, format="packed", min_version=versions[-1])
                voxels = await client.read_voxels(world_id)
                hits = await client.query(world_id, points, min_version=versions[-1])
                out[name] = versions, whole, part, voxels, hits
            return out

    out = asyncio.run(run())
    versions, whole, part, voxels, hits = out["lean"]
    assert versions == list(range(1, 6)) == out["httpx"][0], seed
    np.testing.assert_array_equal(whole.distance, oracle_distance(expected, CAP), err_msg=f"seed {seed}")
    np.testing.assert_array_equal(voxels.data, expected, err_msg=f"seed {seed}")
    assert whole.version >= 5 and part.origin == box[0] and part.data.dtype == np.uint16
    np.testing.assert_array_equal(part.data, out["httpx"][2].data, err_msg=f"seed {seed}")
    np.testing.assert_array_equal(part.distance, whole.distance[2:16, 5:21, 3:29])
    np.testing.assert_array_equal(hits.distances, out["httpx"][4].distances)
    np.testing.assert_array_equal(hits.gradients, out["httpx"][4].gradients)


def test_same_errors_as_async_client(server_url, two_worlds):
    world_id = two_worlds[0]
    outside = np.array([[1, 1, 1, 5], [SIZE[0], 0, 0, 5]])
    calls = [
        lambda c: c.edit("000000000000", [edits.sphere((1, 1, 1), 1)]),
        lambda c: c.read_field("000000000000"),
        lambda c: c.edit(world_id, [edits.sphere((4, 4, 4), 2), edits.voxels(outside)]),
        lambda c: c.read_field(world_id, ((0, 0, 0), (64, 64, 64))),
    ]

    async def caught(client, call) -> ServerError:
        with pytest.raises(ServerError) as info:
            await call(client)
        return info.value

    async def run():
        async with LeanConnection(server_url) as lean, AsyncClient(server_url) as reference:
            pairs = [(await caught(lean, call), await caught(reference, call)) for call in calls]
            after = await lean.read_voxels(world_id)  # the connection still serves after errors
            return pairs, after

    pairs, after = asyncio.run(run())
    for mine, theirs in pairs:
        assert type(mine) is type(theirs)
        assert (mine.status, mine.code, mine.message) == (theirs.status, theirs.code, theirs.message)
    assert isinstance(pairs[0][0], NotFound) and pairs[0][0].status == 404 and pairs[0][0].code == "not_found"
    assert isinstance(pairs[2][0], InvalidEdit) and pairs[2][0].status == 422
    assert 400 <= pairs[3][0].status < 500
    assert after.version == 0 and not after.data.any()  # the refused batch changed nothing


# -- against a scripted raw-socket server --------------------------------------------------------------

HANG = object()  # a reply that never comes: wait until the client hangs up


def reply(body: dict, status: int = 200, headers: str = "", ctype: str = "application/msgpack") -> bytes:
    data = wire.encode(body) if ctype == "application/msgpack" else body
    return (f"HTTP/1.1 {status} X\r\ncontent-type: {ctype}\r\ncontent-length: {len(data)}\r\n{headers}\r\n"
            .encode() + data)


class RawServer:
    """Answers each request with the next scripted reply (given as ``(seconds, reply)``, after that
    delay); records requests and connections. A reply containing ``connection: close``, or followed
    by ``None`` in the script, ends its connection."""

    def __init__(self, *replies):
        self.replies = list(replies)
        self.requests: list[bytes] = []
        self.connections = 0
        self.hung_up = 0  # connections the client closed while the server owed an answer

    async def __aenter__(self) -> "RawServer":
        self.server = await asyncio.start_server(self._handle, "127.0.0.1", 0)
        self.url = f"http://127.0.0.1:{self.server.sockets[0].getsockname()[1]}"
        return self

    async def __aexit__(self, *exc_info) -> None:
        self.server.close()

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        try:
            while True:
                head = await reader.readuntil(b"\r\n\r\n")
                length = [int(line[15:]) for line in head.split(b"\r\n") if line.startswith(b"content-length:")]
                self.requests.append(head + await reader.readexactly(length[0] if length else 0))
                answer = self.replies.pop(0)
                if isinstance(answer, tuple):  # (seconds, reply): a slow answer
                    delay, answer = answer
                    await asyncio.sleep(delay)
                if answer is HANG:
                    await reader.read()
                    self.hung_up += 1
                    return
                writer.write(answer)
                await writer.drain()
                if b"connection: close" in answer or (self.replies and self.replies[0] is None):
                    if self.replies and self.replies[0] is None:
                        self.replies.pop(0)
                    return
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            writer.close()


def test_request_bytes_and_parsed_answers():
    batch = [edits.sphere((4, 5, 6), 2.5, colour=9)]
    field = np.arange(24, dtype=np.uint8).reshape(2, 3, 4)

    async def run():
        async with RawServer(reply({"version": 7}), reply({"origin": [1, 2, 3], "version": 7, "data": field})) as srv:
            async with LeanConnection(srv.url + "/prefix/", api_key="key-0123") as conn:
                version = await conn.edit("w1", batch)
                block = await conn.read_field("w1", ((1, 2, 3), (5, 5, 5)), min_version=version)
            return srv, version, block

    srv, version, block = asyncio.run(run())
    host = srv.url.removeprefix("http://")
    body = wire.encode({"edits": normalize(batch)})
    assert srv.requests[0] == (
        f"POST /prefix/v1/worlds/w1/edits HTTP/1.1\r\nhost: {host}\r\nuser-agent: sdfclient-lean\r\n"
        f"authorization: Bearer key-0123\r\naccept: application/msgpack\r\ncontent-type: application/msgpack\r\n"
        f"content-length: {len(body)}\r\n\r\n").encode() + body
    assert srv.requests[1] == (
        f"GET /prefix/v1/worlds/w1/field?min=1,2,3&max=5,5,5&format=distance&min_version=7 HTTP/1.1\r\n"
        f"host: {host}\r\nuser-agent: sdfclient-lean\r\nauthorization: Bearer key-0123\r\n"
        f"accept: application/msgpack\r\n\r\n").encode()
    assert srv.connections == 1  # kept alive
    assert version == 7 and block.version == 7 and block.origin == (1, 2, 3)
    np.testing.assert_array_equal(block.data, field)


def test_connection_close_and_idle_close_reconnect():
    async def run():
        script = (reply({"version": 1}, headers="connection: close\r\n"),  # told
                  reply({"version": 2}), None,                             # closed while idle, untold
                  reply({"version": 3}), reply({"version": 4}))
        async with RawServer(*script) as srv, LeanConnection(srv.url) as conn:
            versions = [await conn.edit("w", [edits.sphere((1, 1, 1), 1)])]
            versions.append(await conn.edit("w", [edits.sphere((1, 1, 1), 1)]))
            await asyncio.sleep(0.1)  # the server's FIN arrives
            versions += [await conn.edit("w", [edits.sphere((1, 1, 1), 1)]) for _ in range(2)]
            return srv, versions

    srv, versions = asyncio.run(run())
    assert versions == [1, 2, 3, 4] and srv.connections == 3 and len(srv.requests) == 4


def test_chunked_and_close_delimited_bodies():
    body = wire.encode({"version": 42})
    chunked = (b"HTTP/1.1 200 OK\r\ncontent-type: application/msgpack\r\ntransfer-encoding: chunked\r\n\r\n"
               + b"%x;ext=1\r\n" % 3 + body[:3] + b"\r\n" + b"%X\r\n" % (len(body) - 3) + body[3:] + b"\r\n"
               + b"0\r\nx-trailer: y\r\n\r\n")
    unbounded = b"HTTP/1.1 200 OK\r\ncontent-type: application/msgpack\r\n\r\n" + wire.encode({"version": 43})

    async def run():
        async with RawServer(chunked, unbounded, None, reply({"version": 44})) as srv, \
                LeanConnection(srv.url) as conn:
            versions = [await conn.edit("w", [edits.sphere((1, 1, 1), 1)]) for _ in range(3)]
            return srv, versions

    srv, versions = asyncio.run(run())
    assert versions == [42, 43, 44] and srv.connections == 2  # the body without a length ended its connection


def test_interim_answers_and_query_values_that_need_quoting():
    interim = b"HTTP/1.1 100 Continue\r\n\r\nHTTP/1.1 102 Processing\r\nx-step: 1\r\n\r\n"

    async def run():
        async with RawServer(interim + reply({"version": 8})) as srv, LeanConnection(srv.url) as conn:
            return await conn.edit("w", [edits.sphere((1, 1, 1), 1)])

    assert asyncio.run(run()) == 8
    assert lean._query({"min": "-1,2,3", "format": "distance"}) == "min=-1,2,3&format=distance"
    assert lean._query({"min": "1,2,3", "q": "a b&c=d"}) == "min=1%2C2%2C3&q=a+b%26c%3Dd"  # urlencode's


def test_concurrent_callers_take_turns_on_one_connection():
    async def run():
        async with RawServer(*[reply({"version": v}) for v in range(1, 9)]) as srv, \
                LeanConnection(srv.url) as conn:
            versions = await asyncio.gather(*[conn.edit("w", [edits.sphere((x, 1, 1), 1)]) for x in range(8)])
            return srv, versions

    srv, versions = asyncio.run(run())
    bodies = [wire.decode(request.partition(b"\r\n\r\n")[2]) for request in srv.requests]
    assert [body["edits"][0]["center"][0] for body in bodies] == list(range(8))  # one at a time, in call order
    assert versions == list(range(1, 9)) and srv.connections == 1


def test_one_timer_follows_each_exchange_deadline():
    """The connection keeps one timer for all its exchanges: a deadline that passes while a later
    exchange is in flight raises nothing, and a short timeout after a long one still fires on time."""
    t = 0.5  # the timeout; the rest in proportion, with room for a busy machine

    async def run():
        script = (reply({"version": 1}), (t / 2, reply({"version": 2})), reply({"version": 3}), HANG)
        async with RawServer(*script) as srv, LeanConnection(srv.url, timeout=t) as conn:
            sphere = [edits.sphere((1, 1, 1), 1)]
            versions = [await conn.edit("w", sphere)]
            await asyncio.sleep(0.8 * t)
            versions.append(await conn.edit("w", sphere))  # in flight when the first deadline passes
            await asyncio.sleep(1.5 * t)
            conn.timeout = 30.0
            versions.append(await conn.edit("w", sphere))  # the timer is set 30 s ahead
            conn.timeout = t
            loop = asyncio.get_running_loop()
            start = loop.time()
            with pytest.raises(Timeout):
                await conn.edit("w", sphere)
            waited = loop.time() - start
            await asyncio.sleep(0.05)
            return srv, versions, waited

    srv, versions, waited = asyncio.run(run())
    assert versions == [1, 2, 3] and 0.9 * t < waited < 10 * t
    assert srv.connections == 1 and srv.hung_up == 1


def test_timeout_then_a_fresh_connection():
    async def run():
        async with RawServer(HANG, reply({"version": 5})) as srv:
            async with LeanConnection(srv.url, timeout=0.3) as conn:
                with pytest.raises(Timeout):
                    await conn.edit("w", [edits.sphere((1, 1, 1), 1)])
                version = await conn.edit("w", [edits.sphere((1, 1, 1), 1)])
            await asyncio.sleep(0.05)
            return srv, version

    srv, version = asyncio.run(run())
    assert version == 5 and srv.connections == 2 and srv.hung_up == 1  # the timed-out one was closed


def test_broken_and_unreadable_answers_drop_the_connection():
    cut = b"HTTP/1.1 200 OK\r\ncontent-type: application/msgpack\r\ncontent-length: 100\r\n\r\nshort"

    async def run():
        async with RawServer(cut, None, b"SSH-2.0-nonsense\r\n\r\n", reply({"version": 9})) as srv, \
                LeanConnection(srv.url) as conn:
            with pytest.raises(TransportError) as broken:
                await conn.edit("w", [edits.sphere((1, 1, 1), 1)])
            with pytest.raises(ProtocolError):
                await conn.edit("w", [edits.sphere((1, 1, 1), 1)])
            return srv, broken.value, await conn.edit("w", [edits.sphere((1, 1, 1), 1)])

    srv, broken, version = asyncio.run(run())
    assert not isinstance(broken, Timeout) and version == 9 and srv.connections == 3


def test_error_bodies_map_as_in_async_client():
    limited = reply({"error": {"code": "rate_limited", "message": "slow down"}}, status=429,
                    headers="retry-after: 2\r\n")
    plain = reply(b"upstream exploded", status=502, ctype="text/plain")

    async def run():
        found = []
        for make in (LeanConnection, AsyncClient):
            async with RawServer(limited, plain) as srv, make(srv.url) as client:
                for _ in range(2):
                    with pytest.raises(ServerError) as info:
                        await client.edit("w", [edits.sphere((1, 1, 1), 1)])
                    found.append(info.value)
        return found

    lean_429, lean_502, httpx_429, httpx_502 = asyncio.run(run())
    assert isinstance(lean_429, RateLimited) and lean_429.retry_after_s == 2.0 and lean_429.code == "rate_limited"
    for mine, theirs in ((lean_429, httpx_429), (lean_502, httpx_502)):
        assert type(mine) is type(theirs)
        assert (mine.status, mine.code, mine.message, mine.retry_after_s) == \
            (theirs.status, theirs.code, theirs.message, theirs.retry_after_s)


def test_refuses_other_schemes_and_reports_unreachable_servers():
    for url in ("https://127.0.0.1:8000", "ws://127.0.0.1:8000", "127.0.0.1:8000"):
        with pytest.raises(ValueError, match="plain http"):
            LeanConnection(url)

    async def run():
        async with LeanConnection(f"http://127.0.0.1:{free_port()}", timeout=5) as conn:
            with pytest.raises(TransportError) as info:
                await conn.edit("w", [edits.sphere((1, 1, 1), 1)])
            return info.value

    assert not isinstance(asyncio.run(run()), Timeout)
