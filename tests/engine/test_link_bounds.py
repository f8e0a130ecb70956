"""The rest of the links' rules, without a device: an API process believes no engine that cannot
prove itself and takes no answer frame past the link's limit (stand-in engines on asyncio
servers); a request past the limit fails alone and is not sent; an engine cuts a batch of
answers to fit; a header past a reader's limit allocates nothing; Unix sockets only in a private
directory, TCP only with a credential."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import tempfile

import pytest

from sdfserver.api.engine_client import EngineClient, default_limits
from sdfserver.engine import frames, links
from sdfserver.engine import messages as msg
from sdfserver.engine.proc import EngineAddress
from sdfserver.engine.transport import EngineTransport
from sdfserver.errors import NotReady, TooLarge

SMALL = links.LinkLimits(request_bytes=4096, answer_bytes=10_000)


class Echo:
    """An engine's service that answers a request with an id under 10 with that many bytes, and
    leaves the others for the test to answer."""

    def __init__(self, send):
        self.send = send

    def handle(self, client, request):
        if request.id < 10:
            self.send(client, msg.Reply(request.id, b"x" * request.id))

    def update_for(self, client, news):
        return None

    def forget(self, client):
        pass


@contextlib.contextmanager
def ipc_engine(limits: links.LinkLimits):
    with tempfile.TemporaryDirectory() as directory:
        address = EngineAddress(0, "", f"ipc://{directory}/in", f"ipc://{directory}/out")
        transport = EngineTransport(Echo, address, limits)
        transport.start()
        try:
            yield address, transport
        finally:
            transport.stop()


def test_a_header_past_the_readers_limit_raises_before_anything_is_allocated():
    reader = frames.FrameReader(limit=100)
    assert reader.feed(frames.frame(b"y" * 100)) == [b"y" * 100]
    with pytest.raises(frames.FrameTooLarge):
        reader.feed((2**32 - 1).to_bytes(frames.HEADER, "little"))
    assert reader.space() is None  # no buffer was set aside for it


def test_a_reader_told_to_take_one_frame_keeps_the_rest_for_its_next_limit():
    reader = frames.FrameReader(limit=10)
    stream = frames.frame(b"hello") + frames.frame(b"z" * 5000)
    assert reader.feed(stream, most=1) == [b"hello"]
    reader.limit = 1 << 20
    assert reader.feed(b"") == [b"z" * 5000]


def test_an_engine_listens_on_a_unix_socket_only_in_a_directory_closed_to_other_users():
    with tempfile.TemporaryDirectory() as directory:
        os.chmod(directory, 0o755)
        with pytest.raises(PermissionError, match="only this user can open"):
            frames.listen(f"ipc://{directory}/in")
        os.chmod(directory, 0o700)
        frames.listen(f"ipc://{directory}/in").close()


def test_an_engine_listens_on_tcp_only_with_a_credential():
    address = EngineAddress(0, "", "tcp://127.0.0.1:1", "tcp://127.0.0.1:2")
    with pytest.raises(ValueError, match="needs a link credential"):
        EngineTransport(Echo, address, default_limits())


def test_a_request_past_the_links_limit_fails_alone_and_is_not_sent():
    with ipc_engine(default_limits()) as (address, _):
        async def main():
            client = EngineClient(address.input, address.output, limits=SMALL)
            await client.start()
            try:
                with pytest.raises(TooLarge, match="link's limit"):
                    await client.call(msg.ApplyEdits(client.next_id(), "w", b"e" * 5000))
                return await client.call(msg.Status(2))  # the same connection, still there
            finally:
                await client.stop()

        assert asyncio.run(main()) == b"xx"


def test_an_engine_cuts_a_batch_of_answers_to_the_links_limit_and_fails_one_past_it():
    """Six answers of 3,000 bytes completed together leave as frames of at most 10,000 bytes
    (the client takes no larger one); an answer of 20,000 bytes alone fails as TooLarge."""
    with ipc_engine(SMALL) as (address, transport):
        async def main():
            client = EngineClient(address.input, address.output, limits=SMALL)
            await client.start()
            try:
                def answer_together():
                    with transport.holding():
                        for i in range(10, 16):
                            transport.send(client.identity, msg.Reply(i, b"a" * 3000))
                calls = [asyncio.ensure_future(client.call(msg.Status(i))) for i in range(10, 16)]
                await asyncio.sleep(0.2)
                await asyncio.to_thread(answer_together)
                together = await asyncio.wait_for(asyncio.gather(*calls), 10)
                large = asyncio.ensure_future(client.call(msg.Status(16)))
                await asyncio.sleep(0.2)
                transport.send(client.identity, msg.Reply(16, b"b" * 20_000))
                with pytest.raises(TooLarge, match="link's limit of 10000 bytes"):
                    await asyncio.wait_for(large, 10)
                return together
            finally:
                await client.stop()

        assert asyncio.run(main()) == [b"a" * 3000] * 6


# -- stand-in engines, for what an API process believes ----------------------------------------


async def stand_in_engine(credential: bytes | None, misbehave, heard: list[bytes], impostor: bool = False):
    """Two listeners that prove themselves with ``credential`` (an impostor: a challenge, then a
    proof made up without it; None: no proof at all, a welcome straight away, as an engine of
    the old protocol did), then ``misbehave(role, writer)``; what reaches them after the proof
    is kept in ``heard``."""
    writers: list[asyncio.StreamWriter] = []

    async def serve(role: bytes, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writers.append(writer)
        try:
            if credential is not None:
                side = links.EngineSide(credential, role)
                writer.write(side.opening())
                size = int.from_bytes(await reader.readexactly(frames.HEADER), "little")
                hello = await reader.readexactly(size)
                writer.write(frames.frame(os.urandom(links.MAC_BYTES)) if impostor else side.heard(hello)[1])
            if role == links.ANSWERS:
                writer.write(frames.frame(links.WELCOME))
            await misbehave(role, writer)
            heard.append(await reader.read(1 << 16))
        except (asyncio.IncompleteReadError, ConnectionError):
            pass  # the client left

    servers = [await asyncio.start_server(lambda r, w, role=role: serve(role, r, w), "127.0.0.1", 0)
               for role in (links.REQUESTS, links.ANSWERS)]
    ports = [s.sockets[0].getsockname()[1] for s in servers]
    return (servers, writers), f"tcp://127.0.0.1:{ports[0]}", f"tcp://127.0.0.1:{ports[1]}"


async def close_all(stand_in) -> None:
    """Stops the listeners, closes their connections, then waits for the listeners: since Python
    3.12.1 ``Server.wait_closed`` also waits for every connection's handler to end."""
    servers, writers = stand_in
    await asyncio.sleep(0.05)  # a connection being accepted gets its handler (and writer) first
    for server in servers:
        server.close()
    for writer in writers:
        writer.close()
        with contextlib.suppress(ConnectionError):
            await writer.wait_closed()
    for server in servers:
        await server.wait_closed()


async def nothing(role, writer):
    pass


@pytest.mark.parametrize("impostor", ["made-up proof", "no proof"])
def test_an_api_process_believes_no_engine_that_cannot_prove_itself(impostor, caplog):
    """A stand-in engine that answers the client's proof with one made up without the
    credential, or welcomes it with no proof at all: the client is never welcomed, says why
    once, and sends it no request."""
    credential = links.new_credential()

    async def main():
        heard: list[bytes] = []
        servers, requests, answers = await stand_in_engine(
            links.new_credential() if impostor == "made-up proof" else None, nothing, heard, impostor=True)
        client = EngineClient(requests, answers, credential, SMALL)
        client._loop = asyncio.get_running_loop()
        try:
            for _ in range(3):
                with pytest.raises(ConnectionError):
                    await client._open()
            with pytest.raises(NotReady):
                await client.call(msg.Status(1))
        finally:
            await close_all(servers)
        return heard

    with caplog.at_level(logging.ERROR, logger="sdfserver"):
        heard = asyncio.run(main())
    assert not any(frames.FrameReader().feed(h) for h in heard if h)  # no request reached it
    said = [r.getMessage() for r in caplog.records if "is not believed" in r.getMessage()]
    assert len(said) == 1, said  # once, not once an attempt


def test_an_answer_frame_past_the_links_limit_ends_the_connection():
    credential = links.new_credential()

    async def huge_header(role, writer):
        if role == links.ANSWERS:
            await asyncio.sleep(0.2)
            writer.write((SMALL.answer_bytes + 1).to_bytes(frames.HEADER, "little"))

    async def main():
        servers, requests, answers = await stand_in_engine(credential, huge_header, [])
        client = EngineClient(requests, answers, credential, SMALL)
        await client.start()
        try:
            with pytest.raises(NotReady, match="went away"):
                await asyncio.wait_for(client.call(msg.Status(1)), 5)
        finally:
            await client.stop()
            await close_all(servers)

    asyncio.run(main())
