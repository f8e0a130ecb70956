"""An API process's side of one engine: typed requests out, replies and chunk updates in.

``EngineClient`` speaks to an engine process over ZeroMQ: requests PUSHed as ``[identity,
request]``, answers received on a DEALER that carries the same identity, read by the event loop
when the DEALER's descriptor wakes it. Each request has an
id; its future is completed when the ``Reply`` with that id arrives. A subscription's updates
go to the callback given at ``subscribe``; the callback keeps them in a single-slot mailbox.

``LocalEngineClient`` is the same interface on an engine running in this process (tests and
tools): the same messages, encoded and decoded as on the wire, handed to the same
``EngineService``.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import os
from typing import Any, Callable

import msgspec
import zmq
from zmq.utils.monitor import recv_monitor_message

from sdfserver.engine import messages as msg
from sdfserver.errors import InvalidInput, NotReady

log = logging.getLogger("sdfserver")
ENCODE = msg.REQUEST_ENCODER.encode
DECODE_OUTPUTS = msg.OUTPUTS_DECODER.decode
HELLO_TIMEOUT_S = 30.0


class BaseClient:
    def __init__(self) -> None:
        self._ids = itertools.count(1)
        self._pending: dict[int, asyncio.Future] = {}
        self._updates: dict[int, Callable[[msg.ChunkUpdate], None]] = {}
        self.lost: str | None = None  # why this engine can no longer answer

    def next_id(self) -> int:
        return next(self._ids)

    async def call(self, request: Any) -> Any:
        """Send ``request`` (its ``id`` from ``next_id``) and return its reply's result."""
        future = asyncio.get_running_loop().create_future()
        self._pending[request.id] = future
        try:
            self._send(request)
        except (OverflowError, msgspec.EncodeError) as exc:  # a number no engine could take
            self._pending.pop(request.id, None)
            raise InvalidInput(f"a value of the request is out of range: {exc}") from None
        except BaseException:
            self._pending.pop(request.id, None)
            raise
        return await future

    def tell(self, request: Any) -> None:
        """Send a request nobody waits for (its id is 0: the engine answers nothing)."""
        self._send(request)

    def on_updates(self, number: int, deliver: Callable[[msg.ChunkUpdate], None] | None) -> None:
        if deliver is None:
            self._updates.pop(number, None)
        else:
            self._updates[number] = deliver

    def _send(self, request: Any) -> None:
        raise NotImplementedError

    def _take(self, outputs: msg.Outputs) -> None:
        for item in outputs.items:
            if isinstance(item, msg.Reply):
                future = self._pending.pop(item.id, None)
                if future is None or future.done():
                    continue
                if item.failure is not None:
                    try:
                        msg.raise_failure(item.failure)
                    except Exception as exc:
                        future.set_exception(exc)
                else:
                    future.set_result(item.result)
            else:
                deliver = self._updates.get(item.subscription)
                if deliver is not None:
                    deliver(item)

    def fail_all(self, exc: BaseException) -> None:
        pending, self._pending = self._pending, {}
        for future in pending.values():
            if not future.done():
                future.set_exception(exc)


class EngineClient(BaseClient):
    """Plain (blocking-capable) ZeroMQ sockets driven by the event loop: a PUSH with no
    high-water mark never blocks, so a send completes at once; the DEALER's file descriptor
    wakes the loop, which then takes every answer waiting (ZeroMQ's descriptor is
    edge-triggered: drained in full each time)."""

    def __init__(self, input_address: str, output_address: str):
        super().__init__()
        self.input_address, self.output_address = input_address, output_address
        self.identity = f"api-{os.getpid()}-{id(self):x}".encode()
        self._context: zmq.Context | None = None
        self._push: zmq.Socket | None = None
        self._dealer: zmq.Socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._fd: int | None = None
        self._monitor: zmq.Socket | None = None
        self._monitor_fd: int | None = None

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._context = zmq.Context()
        welcomed = self._loop.create_future()
        self._connect(welcomed)
        await asyncio.wait_for(welcomed, HELLO_TIMEOUT_S)

    def relocate(self, input_address: str, output_address: str) -> None:
        """The engine now listens at other addresses: what it held failed when it went away;
        new sockets there (the engine answers once it has heard this process's hello)."""
        self._close_sockets()
        self.input_address, self.output_address = input_address, output_address
        self._connect(None)

    def _connect(self, welcomed: asyncio.Future | None) -> None:
        self._push = self._context.socket(zmq.PUSH)
        self._push.setsockopt(zmq.SNDHWM, 0)
        self._push.setsockopt(zmq.LINGER, 0)
        self._push.connect(self.input_address)
        self._dealer = self._context.socket(zmq.DEALER)
        self._dealer.setsockopt(zmq.IDENTITY, self.identity)
        self._dealer.setsockopt(zmq.RCVHWM, 0)
        self._dealer.setsockopt(zmq.LINGER, 0)
        self._dealer.connect(self.output_address)
        # The engine's ROUTER can answer this process only once it has heard from it.
        self._dealer.send(b"hello")
        self._fd = self._dealer.getsockopt(zmq.FD)
        self._loop.add_reader(self._fd, self._drain, welcomed)
        self._drain(welcomed)
        # An engine that goes away (a cluster's engine actor restarting) takes the requests it
        # held with it: they fail at once, 503, rather than wait for answers that cannot come.
        # ZeroMQ reconnects by itself when the engine listens again.
        self._monitor = self._dealer.get_monitor_socket(zmq.EVENT_DISCONNECTED)
        self._monitor_fd = self._monitor.getsockopt(zmq.FD)
        self._loop.add_reader(self._monitor_fd, self._watch_connection)
        self._watch_connection()

    def _watch_connection(self) -> None:
        while self._monitor.getsockopt(zmq.EVENTS) & zmq.POLLIN:
            event = recv_monitor_message(self._monitor, zmq.NOBLOCK)
            if event["event"] == zmq.EVENT_DISCONNECTED:
                log.warning("engine at %s went away; %d requests fail", self.output_address, len(self._pending))
                self.fail_all(NotReady(f"the engine at {self.output_address} went away (restarting?); "
                                       "retry the request"))

    async def stop(self) -> None:
        self._close_sockets()
        if self._context is not None:
            self._context.term()

    def _close_sockets(self) -> None:
        if self._fd is not None and self._loop is not None:
            self._loop.remove_reader(self._fd)
            self._fd = None
        if self._monitor is not None and self._loop is not None:
            self._loop.remove_reader(self._monitor_fd)
            self._dealer.disable_monitor()
            self._monitor.close(0)
            self._monitor = None
        for sock in (self._push, self._dealer):
            if sock is not None:
                sock.close(0)
        self._push = self._dealer = None

    def _send(self, request: Any) -> None:
        self._push.send_multipart([self.identity, ENCODE(request)], flags=zmq.NOBLOCK)

    def _drain(self, welcomed: asyncio.Future | None = None) -> None:
        dealer = self._dealer
        while dealer.getsockopt(zmq.EVENTS) & zmq.POLLIN:
            payload = dealer.recv(zmq.NOBLOCK)
            try:
                outputs = DECODE_OUTPUTS(payload)
            except Exception:
                log.exception("an undecodable engine output was dropped")
                continue
            if welcomed is not None and not welcomed.done():
                welcomed.set_result(None)  # the welcome: an empty batch
            try:
                self._take(outputs)
            except Exception:  # the rest must still be read: the descriptor wakes the loop only once
                log.exception("delivering engine outputs failed")


class LocalEngineClient(BaseClient):
    """An engine in this process, through the same service and the same encoding."""

    IDENTITY = b"local"

    def __init__(self, engine: Any, settings: Any):
        from sdfserver.engine.access import Doorkeeper, RateLimiter
        from sdfserver.engine.service import EngineService

        super().__init__()
        self.engine = engine
        limiter = RateLimiter(settings.rate_limit_per_s, settings.rate_limit_burst)
        doorkeeper = Doorkeeper(limiter, engine.owner_of, lambda: list(engine.owners.values()))
        journal = engine.journal

        def writes_failure() -> str | None:
            committer = getattr(getattr(journal, "storage", None), "committer", None)
            failed = getattr(committer, "failure", None)
            return None if failed is None else str(failed)

        self.service = EngineService(engine, doorkeeper, self._deliver, writes_failure=writes_failure)
        self._loop: asyncio.AbstractEventLoop | None = None

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()

    async def stop(self) -> None:
        pass

    def _send(self, request: Any) -> None:
        if self._loop is None:  # an app served without its lifespan (httpx.ASGITransport)
            self._loop = asyncio.get_running_loop()
        self.service.handle(self.IDENTITY, msg.REQUEST_DECODER.decode(ENCODE(request)))

    def _deliver(self, client: bytes, item: Any) -> None:  # any thread
        from sdfserver.engine.service import SubscriptionNews

        if isinstance(item, SubscriptionNews):
            item = self.service.update_for(client, item)
            if item is None:
                return
        outputs = DECODE_OUTPUTS(ENCODE(msg.Outputs([item])))
        try:
            self._loop.call_soon_threadsafe(self._take, outputs)
        except RuntimeError:  # the loop closed: nobody waits
            pass
