"""The two connections of an ``EngineClient`` to its engine, as event-loop protocols: each
first proves this API process holds the engine's credential and has the engine prove the same
(``engine/links.py``), then carries frames; one that breaks the link's rules is aborted, and the
client opens both again."""

from __future__ import annotations

import asyncio
import logging
import socket
from typing import TYPE_CHECKING, Callable

from sdfserver.engine import frames, links

if TYPE_CHECKING:
    from sdfserver.api.engine_client import EngineClient

log = logging.getLogger("sdfserver")
ANSWER_READ_BYTES = 1 << 18  # what one read of the answers socket takes, outside a large answer


class AnswersLink(asyncio.BufferedProtocol):
    """The engine's answers, frame by frame, once the engine has proven itself; the first (an
    empty batch) is its welcome. The event loop reads into this protocol's buffer, or straight
    into a large answer's own (``FrameReader.space``): a megabyte answer in a read or two,
    copied once."""

    def __init__(self, client: EngineClient, generation: int, proof: links.ApiSide, welcomed: asyncio.Future):
        self.client, self.generation, self.proof, self.welcomed = client, generation, proof, welcomed
        self.reader = frames.FrameReader(client.limits.answer_bytes if proof.proven else links.HELLO_BYTES)
        self.buffer = memoryview(bytearray(ANSWER_READ_BYTES))
        self.into_frame = False  # the last buffer given was a large frame's
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport
        transport.write(self.proof.opening())

    def get_buffer(self, sizehint: int) -> memoryview:
        space = self.reader.space()
        self.into_frame = space is not None
        return self.buffer if space is None else space

    def buffer_updated(self, nbytes: int) -> None:
        try:
            if self.into_frame:
                payloads = self.reader.filled(nbytes)
            else:
                payloads = self.reader.feed(self.buffer[:nbytes], None if self.proof.proven else 1)
                while payloads and not self.proof.proven:  # the engine's challenge, then its proof
                    self.transport.write(self.proof.heard(payloads.pop()))
                    if self.proof.proven:
                        self.reader.limit = self.client.limits.answer_bytes
                    payloads = self.reader.feed(b"", None if self.proof.proven else 1)
        except (frames.FrameTooLarge, links.LinkRefused) as exc:
            self.refuse(exc)
            return
        for payload in payloads:
            if not self.welcomed.done():
                if payload != links.WELCOME:
                    self.refuse(links.LinkRefused("welcome", "the engine's first frame is not its welcome"))
                    return
                self.welcomed.set_result(None)
                continue
            self.client._arrived(payload)

    def refuse(self, exc: Exception) -> None:
        """The engine did not prove itself, or sent a frame past the link's limit: the
        connection ends (its requests fail; the client connects again)."""
        if not self.welcomed.done():
            self.welcomed.set_exception(exc if isinstance(exc, links.LinkRefused) else ConnectionError(str(exc)))
        else:
            log.error("the engine at %s broke the link: %s", self.client.output_address, exc)
        self.transport.abort()

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.welcomed.done():
            self.welcomed.set_exception(ConnectionError("the engine closed the connection"))
        self.client._went_away(self.generation)


class RequestsLink(asyncio.Protocol):
    """The requests' connection: the engine speaks on it only to prove itself."""

    def __init__(self, client: EngineClient, generation: int, proof: links.ApiSide, proven: asyncio.Future):
        self.client, self.generation, self.proof, self.proven = client, generation, proof, proven
        self.reader = frames.FrameReader(links.HELLO_BYTES)
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport
        transport.write(self.proof.opening())
        if self.proof.proven:
            self.proven.set_result(None)

    def data_received(self, data: bytes) -> None:
        try:
            for payload in self.reader.feed(data):
                if self.proof.proven:
                    raise links.LinkRefused("unexpected", "the engine wrote on the requests' connection")
                self.transport.write(self.proof.heard(payload))
                if self.proof.proven:
                    self.proven.set_result(None)
        except (frames.FrameTooLarge, links.LinkRefused) as exc:
            if not self.proven.done():
                self.proven.set_exception(exc if isinstance(exc, links.LinkRefused) else ConnectionError(str(exc)))
            else:
                log.error("the engine at %s broke the link: %s", self.client.input_address, exc)
            self.transport.abort()

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.proven.done():
            self.proven.set_exception(ConnectionError("the engine closed the connection"))
        self.client._went_away(self.generation)


async def open_link(loop: asyncio.AbstractEventLoop, address: str, protocol: Callable[[], asyncio.Protocol]):
    family, target = frames.family_and_target(address)
    if family == socket.AF_UNIX:
        transport, made = await loop.create_unix_connection(protocol, target)
        frames.prepare(transport.get_extra_info("socket"))
        return transport, made
    return await loop.create_connection(protocol, *target)  # TCP_NODELAY: asyncio's and uvloop's default
