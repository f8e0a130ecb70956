"""A front process: HTTP parsing for the hot requests, on a core of its own.

The server process shares one GIL between its event loop and its engine thread; under many
clients the loop's HTTP work (parsing, bodies, validation, answers) caps the whole server.
With ``--fronts N`` the server starts N of these (``fronts.py``). Each listens on the
server's port (``SO_REUSEPORT``: the kernel spreads connections over them) and runs uvicorn
with ``FrontProtocol``:

- a request the fast lane answers (``fastlane.lane_route``) is served here, by the lane's
  own handlers; its engine command travels over the link (``link.py``) to the server
  process, which rate-limits, checks the world's owner, runs it and sends the result back;
- any other request hands its whole connection to the server process, with the bytes
  read so far, before anything is answered: WebSockets, world management, the web page,
  /metrics and the rest are served there exactly as without fronts.

Run by the server process only: ``python -m sdfserver.api.front LINK_FD HANDOFF_FD``.
"""

from __future__ import annotations

import asyncio
import contextvars
import functools
import itertools
import logging
import socket
import sys
import urllib.parse
from typing import Any

import httptools
import uvicorn
from starlette.datastructures import State
from starlette.requests import Request
from starlette.types import Receive, Scope, Send

from sdfserver.api import auth, link
from sdfserver.api.coalesce import CoalescingHttpToolsProtocol
from sdfserver.api.errors import Answered
from sdfserver.api.fastlane import FastLane, lane_route
from sdfserver.api.logs import configure_logging
from sdfserver.engine.commands import ApplyEdits, CommandCalls
from sdfserver.errors import NotReady
from sdfserver.settings import Settings
from sdfserver.storage.codec import encode_batch

log = logging.getLogger("sdfserver.front")
# (key name, admin, client address) of the request being served: set by front_guard, sent
# with its engine command
CALLER: contextvars.ContextVar[tuple[str | None, bool, str]] = contextvars.ContextVar("caller")
BYTES_OUT_EVERY_S = 1.0


async def front_guard(request: Request) -> None:
    """The key only: the server process rate-limits and checks the owner (``fronts.FrontDesk``)."""
    principal = auth.authenticate(request)
    CALLER.set((principal.name, principal.admin, auth.client_host(request)))


class RemoteEngine(CommandCalls):
    """What the lane's handlers call ``request.app.state.engine``: the server's engine, over the link."""

    def __init__(self, max_wait_s: float):
        self.max_wait_s = max_wait_s
        self.link: link.LinkProtocol | None = None
        self._replies: dict[int, asyncio.Future] = {}
        self._ids = itertools.count()

    async def apply_edits(self, world_id: str, edits: list, wire: list) -> int:
        # The batch's log record travels encoded: bytes cross the link cheaply, and unpickling
        # its dicts was a large part of the server event loop's GIL time under load.
        return await self.call(ApplyEdits(world_id, edits, encode_batch(wire)))

    async def call(self, command: Any) -> Any:
        if self.link is None or self.link.transport is None:
            raise NotReady("the front has lost its server process")
        future = asyncio.get_running_loop().create_future()
        request_id = next(self._ids)
        self._replies[request_id] = future
        self.link.send(("call", request_id, CALLER.get(), command))
        return await future

    def on_reply(self, request_id: int, ok: bool, payload: Any) -> None:
        future = self._replies.pop(request_id, None)
        if future is None or future.done():
            return
        if ok:
            future.set_result(payload)
        else:
            future.set_exception(Answered(*payload))

    def fail_all(self) -> None:
        replies, self._replies = self._replies, {}
        for future in replies.values():
            if not future.done():
                future.set_exception(NotReady("the front has lost its server process"))


class BytesOut:
    """The lane's ``metrics.bytes_out`` here: counted, and sent to the server's /metrics now and then."""

    def __init__(self) -> None:
        self.unsent = 0

    def inc(self, amount: float = 1) -> None:
        self.unsent += int(amount)


class FrontApp:
    """ASGI: only the lane's requests reach it (``FrontProtocol`` hands the rest over)."""

    def __init__(self, settings: Settings, engine: RemoteEngine):
        self.state = State()
        self.state.settings = settings
        self.state.engine = engine
        self.state.gatekeeper = auth.Gatekeeper(auth.parse_keys(settings.api_keys, settings.api_key_file))
        self.state.metrics = State({"bytes_out": BytesOut()})
        self.lane = FastLane(self._elsewhere, self, guard=front_guard)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        await self.lane(scope, receive, send)

    async def _elsewhere(self, scope: Scope, receive: Receive, send: Send) -> None:
        raise RuntimeError(f"a front was asked for {scope.get('path')!r}, which it hands over")


class FrontProtocol(CoalescingHttpToolsProtocol):
    """uvicorn's protocol that serves the lane's requests and hands every other connection over.

    It keeps the bytes of the request being parsed until its headers are complete, the
    moment a request's route is known. A request the lane answers goes on as under uvicorn;
    for any other, reading stops, the answers in flight are sent, and the socket and the
    request's bytes go to the server process, which reads on from there.
    """

    def __init__(self, *args: Any, channel: socket.socket, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.channel = channel
        self._raw: bytearray | None = bytearray()  # this request's bytes, until its route is known
        self._request_done = True  # the next bytes begin a request
        self._chunk_began_request = False
        self._began_in_chunk = False
        self._whole = True  # the request's bytes start at a chunk's start (not pipelined behind another)
        self._leaving = False

    def data_received(self, data: bytes) -> None:  # uvicorn's, with the hand-over
        if self._leaving:
            self._raw += data  # type: ignore[operator]
            return
        self._chunk_began_request, self._began_in_chunk = self._request_done, False
        if self._request_done:
            self._raw, self._request_done = bytearray(data), False
        elif self._raw is not None:
            self._raw += data
        self._unset_keepalive_if_required()
        try:
            self.parser.feed_data(data)
        except httptools.HttpParserUpgrade:
            pass  # a WebSocket: its headers already set _leaving
        except httptools.HttpParserError:
            if not self._leaving:
                self.logger.warning("Invalid HTTP request received.")
                self.send_400_response("Invalid HTTP request received.")
                return
        if self._leaving:
            self._hand_over()

    def on_message_begin(self) -> None:
        self._whole = self._chunk_began_request and not self._began_in_chunk
        self._began_in_chunk = True
        super().on_message_begin()

    def on_headers_complete(self) -> None:
        path = httptools.parse_url(self.url).path.decode("ascii")
        if "%" in path:
            path = urllib.parse.unquote(path)
        if self.parser.should_upgrade() or lane_route(self.parser.get_method().decode("ascii"), path) is None:
            self._leaving = True
            return
        self._raw = None  # served here: nothing more to keep
        super().on_headers_complete()

    def on_body(self, body: bytes) -> None:
        if not self._leaving:
            super().on_body(body)

    def on_message_complete(self) -> None:
        if self._leaving:
            return
        self._request_done = True
        super().on_message_complete()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if self._leaving:  # a request to hand over came while this answer was in flight
            self._hand_over()

    def _hand_over(self) -> None:
        self.flow.pause_reading()
        self._unset_keepalive_if_required()
        if self.transport.is_closing():
            return
        if self.cycle is not None and not self.cycle.response_complete:
            return  # the answer in flight first: on_response_complete calls again
        if not self._whole:  # its first bytes went into the parser with the request before it
            self.send_400_response("A request for the server process was pipelined behind another; "
                                   "send it once the answers before it have arrived.")
            return
        self.transport.flush()
        if self.transport.get_write_buffer_size():  # an answer still on its way out
            self.loop.call_later(0.002, self._hand_over)
            return
        try:
            link.send_connection(self.channel, self.transport.get_extra_info("socket"), bytes(self._raw or b""))
        except OSError as exc:
            log.error("could not hand a connection to the server process: %s", exc)
        # Ours closes; the server process holds the socket open from here.
        self.transport.inner.abort()


async def serve(link_socket: socket.socket, channel: socket.socket) -> None:
    loop = asyncio.get_running_loop()
    hello: asyncio.Future = loop.create_future()
    engine = RemoteEngine(max_wait_s=0.0)
    server: uvicorn.Server | None = None

    def on_message(message: Any) -> None:
        if message[0] == "reply":
            engine.on_reply(*message[1:])
        elif not hello.done():
            hello.set_result(message)

    def on_lost() -> None:  # the server process is gone: so is this front
        engine.fail_all()
        if not hello.done():
            hello.set_exception(ConnectionError("the server process closed the link"))
        if server is not None:
            server.should_exit = True

    _, engine.link = await loop.connect_accepted_socket(functools.partial(link.LinkProtocol, on_message, on_lost),
                                                        sock=link_socket)
    _, fields, port = await hello
    settings = Settings(**fields)
    log_config = configure_logging(settings)
    engine.max_wait_s = settings.max_wait_ms / 1e3
    app = FrontApp(settings, engine)
    listener = link.reuseport_socket(settings.host, port)
    config = uvicorn.Config(app, log_config=log_config, log_level=settings.log_level, lifespan="off",
                            http=functools.partial(FrontProtocol, channel=channel),  # type: ignore[arg-type]
                            access_log=settings.access_log, timeout_graceful_shutdown=5)
    server = ListeningServer(config, engine)
    loop.create_task(_send_bytes_out(engine, app.state.metrics.bytes_out))
    await server.serve(sockets=[listener])


class ListeningServer(uvicorn.Server):
    """Tells the server process once it listens: its /readyz waits for every front."""

    def __init__(self, config: uvicorn.Config, engine: RemoteEngine):
        super().__init__(config)
        self.engine = engine

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets=sockets)
        if self.engine.link is not None:
            self.engine.link.send(("listening",))


async def _send_bytes_out(engine: RemoteEngine, counter: BytesOut) -> None:
    while True:
        await asyncio.sleep(BYTES_OUT_EVERY_S)
        if counter.unsent and engine.link is not None:
            engine.link.send(("bytes_out", counter.unsent))
            counter.unsent = 0


def main(argv: list[str]) -> int:
    link_socket = socket.socket(fileno=int(argv[0]))
    channel = socket.socket(fileno=int(argv[1]))
    try:
        import uvloop
        loop_factory = uvloop.new_event_loop
    except ImportError:
        loop_factory = None
    with asyncio.Runner(loop_factory=loop_factory) as runner:
        try:
            runner.run(serve(link_socket, channel))
        except ConnectionError as exc:
            print(f"sdfserver front: {exc}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
