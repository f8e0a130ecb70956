"""The server process's side of its front processes (``front.py``): start them, take their
engine commands, adopt the connections they hand over, start one again if it dies.

``FrontedServer`` is uvicorn's Server without a listening socket of its own: the server
holds the port (``port.py``), the fronts listen on it, and every connection they hand over
joins this server as if it had accepted it (uvicorn's own protocol, its keep-alive and
shutdown handling), starting with the bytes the front read.
"""

from __future__ import annotations

import asyncio
import dataclasses
import functools
import logging
import socket
import subprocess
import sys
import time
from typing import Any, Callable

import numpy as np
import uvicorn

from sdfserver.api import auth, link
from sdfserver.api.desklink import DeskLink
from sdfserver.api.errors import Answered
from sdfserver.engine.commands import ApplyEdits, Completion, Query, Read
from sdfserver.settings import Settings

log = logging.getLogger("sdfserver.fronts")
FRONT_COMMANDS = (ApplyEdits, Query, Read)  # what the lane sends; nothing else is taken from a front
WATCH_EVERY_S = 0.5
RESTART_DELAY_S = 5.0  # a front that lived less than this is started again only after it
DIRECT_REPLY_BYTES = 64 << 10  # a reply with more array bytes is pickled by the link's writer thread


class FrontDesk:
    """One front's link: its commands to the engine (after the rate limit and the owner check),
    taken on the link's reader thread, and the results back, sent from whichever thread
    completes them."""

    def __init__(self, state: Any, sock: socket.socket, name: str):
        self.engine, self.gate, self.metrics = state.engine, state.gatekeeper, state.metrics
        self.link = DeskLink(sock, self.on_message, name)
        self.listening = False  # the front said it listens on the port

    def on_message(self, message: Any) -> None:  # the link's reader thread
        if message[0] == "call":
            self._call(*message[1:])
        elif message[0] == "bytes_out":
            self.metrics.bytes_out.inc(message[1])
        elif message[0] == "listening":
            self.listening = True

    def _call(self, request_id: int, caller: tuple[str | None, bool, str], command: Any) -> None:
        try:
            if type(command) not in FRONT_COMMANDS:
                raise TypeError(f"not a command a front may send: {type(command).__name__}")
            name, admin, client = caller
            principal = auth.OPEN if self.gate.open else auth.Principal(name, admin)
            auth.admit(self.gate, self.engine, principal, client, command.world_id)
            self.engine.submit(command, Completion(functools.partial(self._done, request_id)))
        except Exception as exc:
            self._reply(request_id, exc)

    def _done(self, request_id: int, ok: bool, result: Any) -> None:  # the engine's or the committer's thread
        if ok:
            self.link.send(("reply", request_id, True, result), small=_array_bytes(result) <= DIRECT_REPLY_BYTES)
        else:
            self._reply(request_id, result)

    def _reply(self, request_id: int, exc: BaseException) -> None:
        answer = Answered.of(exc)  # the one mapping to status and body, applied here
        self.link.send(("reply", request_id, False, (answer.status, answer.body, answer.headers)))


def _array_bytes(result: Any) -> int:
    """The bytes of the arrays in a command's result (a read's or a query's); 0 for a version."""
    if not dataclasses.is_dataclass(result):
        return 0
    return sum(v.nbytes for v in vars(result).values() if isinstance(v, np.ndarray))


class Front:
    """One front process and its two socket pairs."""

    def __init__(self, index: int):
        self.index = index
        self.started = time.monotonic()
        self.desk: FrontDesk | None = None
        link_here, link_there = socket.socketpair()
        self.channel, channel_there = link.handoff_pair()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "sdfserver.api.front", str(link_there.fileno()), str(channel_there.fileno())],
            pass_fds=(link_there.fileno(), channel_there.fileno()), stdin=subprocess.DEVNULL)
        link_there.close()
        channel_there.close()
        self.link_socket = link_here
        self.channel.setblocking(False)
        self.receiver = link.ConnectionReceiver(self.channel)


class FrontPool:
    def __init__(self, settings: Settings, state: Any, port: int):
        """``port``: the one the server holds (``port.hold_port``), where the fronts listen."""
        self.settings, self.state, self.port = settings, state, port
        self.fronts: list[Front] = []
        self._protocol_factory: Callable[[], asyncio.Protocol] | None = None
        self._stopping = False
        self._watch: asyncio.Task | None = None

    @property
    def wanted(self) -> int:
        return self.settings.fronts

    @property
    def listening(self) -> int:
        """Fronts up and listening (/readyz answers 503 until all are)."""
        return sum(1 for f in self.fronts if f.desk is not None and f.desk.listening and f.process.poll() is None)

    async def start(self, protocol_factory: Callable[[], asyncio.Protocol]) -> None:
        self._protocol_factory = protocol_factory
        for index in range(self.settings.fronts):
            self.fronts.append(await self._spawn(index))
        self._watch = asyncio.get_running_loop().create_task(self._watch_fronts())
        self.state.fronts = self  # /readyz waits for them
        log.info("listening on http://%s:%d through %d front processes", self.settings.host, self.port,
                 len(self.fronts))

    async def _spawn(self, index: int) -> Front:
        front = Front(index)
        desk = front.desk = FrontDesk(self.state, front.link_socket, name=f"front-{index}")
        desk.link.start()
        desk.link.send(("hello", self.settings.model_dump(), self.port))
        asyncio.get_running_loop().add_reader(front.channel.fileno(), self._take_connections, front)
        return front

    def _take_connections(self, front: Front) -> None:
        loop = asyncio.get_running_loop()
        while True:
            try:
                received = front.receiver.receive()
            except ConnectionError as exc:
                log.error("front %d: %s", front.index, exc)
                continue
            if received is None:
                return
            if received is False:
                loop.remove_reader(front.channel.fileno())
                return
            connection, data = received
            connection.setblocking(False)
            loop.create_task(self._adopt(connection, data))

    async def _adopt(self, connection: socket.socket, data: bytes) -> None:
        try:
            await asyncio.get_running_loop().connect_accepted_socket(functools.partial(self._adopted, data),
                                                                     sock=connection)
        except OSError as exc:  # the client left during the hand-over
            log.info("a handed-over connection closed before it was adopted: %s", exc)
            connection.close()

    def _adopted(self, data: bytes) -> asyncio.Protocol:
        """The server's protocol, given the front's bytes as its connection is made: before the
        transport reads the rest of the request from the socket."""
        assert self._protocol_factory is not None
        protocol = self._protocol_factory()
        connection_made = protocol.connection_made

        def made(transport: asyncio.BaseTransport) -> None:
            connection_made(transport)
            if data:
                protocol.data_received(data)

        protocol.connection_made = made  # type: ignore[method-assign]
        return protocol

    async def _watch_fronts(self) -> None:
        while not self._stopping:
            await asyncio.sleep(WATCH_EVERY_S)
            for i, front in enumerate(self.fronts):
                if front.process.poll() is not None and not self._stopping:
                    # one that dies young waits before the next try: no start-up crash loop
                    delay = RESTART_DELAY_S if time.monotonic() - front.started < RESTART_DELAY_S else 0.0
                    log.error("front process %d exited with %s; starting it again%s", front.index,
                              front.process.returncode, f" in {delay:g} s" if delay else "")
                    self._close(front)
                    await asyncio.sleep(delay)
                    if not self._stopping:
                        self.fronts[i] = await self._spawn(front.index)

    def _close(self, front: Front) -> None:
        if front.channel.fileno() < 0:  # closed already (it died, and stop() came before its restart)
            return
        asyncio.get_running_loop().remove_reader(front.channel.fileno())
        front.channel.close()
        if front.desk is not None:
            front.desk.link.close()
            front.desk.link.join()

    async def stop(self) -> None:
        self._stopping = True
        if self._watch is not None:
            self._watch.cancel()
        for front in self.fronts:
            if front.process.poll() is None:
                front.process.terminate()
        for front in self.fronts:
            await asyncio.get_running_loop().run_in_executor(None, _wait_or_kill, front.process)
            self._close(front)


def _wait_or_kill(process: subprocess.Popen, timeout_s: float = 10.0) -> None:
    try:
        process.wait(timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


class FrontedServer(uvicorn.Server):
    """uvicorn's server, listening through the fronts instead of a socket of its own."""

    def __init__(self, config: uvicorn.Config, pool: FrontPool):
        super().__init__(config)
        self.pool = pool

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets=[])
        if self.should_exit:
            return
        config = self.config

        def protocol() -> asyncio.Protocol:  # as uvicorn's startup makes them for its listeners
            return config.http_protocol_class(config=config, server_state=self.server_state,  # type: ignore
                                              app_state=self.lifespan.state)

        await self.pool.start(protocol)

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        await self.pool.stop()
        await super().shutdown(sockets=sockets)
