"""An API process's side of one engine: typed requests out, replies and chunk updates in.

``EngineClient`` speaks to an engine process over two stream connections (``frames.py``):
requests written to one, answers read from the other as the event loop hears them. Each
connection first proves this process holds the engine's credential, and has the engine prove
the same (``links.py``): nothing is sent to, or believed from, an engine that has not. Each
request has an id; its future is completed when the ``Reply`` with that id arrives. A
subscription's updates go to the callback given at ``subscribe``; the callback keeps them in a
single-slot mailbox. A request past the link's limit fails alone (413) and is not sent; an
answer frame past it ends the connection, as an engine going away does.

``LocalEngineClient`` is the same interface on an engine running in this process (tests and
tools): the same messages, encoded and decoded as on the wire, handed to the same
``EngineService``.
"""

from __future__ import annotations

import asyncio
import functools
import itertools
import logging
import os
from typing import Any, Callable

import msgspec

from sdfserver.api.engine_links import AnswersLink, RequestsLink, open_link
from sdfserver.engine import frames, links
from sdfserver.engine import messages as msg
from sdfserver.errors import InvalidInput, NotReady, TooLarge

log = logging.getLogger("sdfserver")
ENCODE = msg.REQUEST_ENCODER.encode
ENCODE_INTO = msg.REQUEST_ENCODER.encode_into
DECODE_OUTPUTS = msg.OUTPUTS_DECODER.decode
HELLO_TIMEOUT_S = 30.0  # how long an API process starting waits for its engine
WELCOME_TIMEOUT_S = 5.0
RECONNECT_S = 0.1


class BaseClient:
    def __init__(self) -> None:
        self._ids = itertools.count(1)
        self._pending: dict[int, asyncio.Future] = {}
        self._updates: dict[int, Callable[[msg.ChunkUpdate], None]] = {}
        self._dropped: dict[str, int] = {}  # requests told while the engine was away, by type
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
        """Send a request nobody waits for (its id is 0: the engine answers nothing). One told
        while the engine is not connected is dropped: what it said (a count, a subscription's
        credit or its end) died with that engine's state. The drops are said once, when the
        engine is back (``_say_dropped``), not once each."""
        try:
            self._send(request)
        except NotReady:
            kind = type(request).__name__
            self._dropped[kind] = self._dropped.get(kind, 0) + 1

    def _say_dropped(self, where: str) -> None:
        if self._dropped:
            kinds = ", ".join(f"{kind} {n}" for kind, n in sorted(self._dropped.items()))
            log.info("the engine at %s is back; %d messages nobody waited for were dropped while it was away (%s)",
                     where, sum(self._dropped.values()), kinds)
            self._dropped = {}

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
    """Two stream connections to one engine, driven by the event loop: requests are written to
    its input, answers read from its output as they arrive. An engine that goes away (a
    cluster's engine actor restarting) takes the requests it held with it: they fail at once,
    503, rather than wait for answers that cannot come; the client reconnects, trying every
    ``RECONNECT_S``, and meanwhile a request fails at once with the same 503.

    ``credential``: the engine's (``EngineAddress.credential``; None for a Unix socket).
    ``limits``: the server's ``LinkLimits``; None takes those of the default settings (tools
    and tests)."""

    def __init__(self, input_address: str, output_address: str, credential: bytes | None = None,
                 limits: links.LinkLimits | None = None):
        super().__init__()
        self.input_address, self.output_address = input_address, output_address
        self.credential = credential
        self.limits = limits if limits is not None else default_limits()
        self.identity = f"api-{os.getpid()}-{id(self):x}".encode()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._requests: asyncio.Transport | None = None
        self._answers: asyncio.Transport | None = None
        self._generation = 0  # which connections are the current ones
        self._connecting: asyncio.Task | None = None
        self._stopped = False
        self._outbox: list[bytes] | None = None  # this turn's requests, written as it ends
        self._refused_by: str | None = None  # why the engine was last not believed (said once)

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        await asyncio.wait_for(self._connect(), HELLO_TIMEOUT_S)

    def relocate(self, input_address: str, output_address: str) -> None:
        """The engine now listens at other addresses: what it held failed when it went away;
        new connections there."""
        self.input_address, self.output_address = input_address, output_address
        self._disconnect(NotReady(f"the engine moved to {output_address}; retry the request"))
        self._reconnect()

    async def stop(self) -> None:
        self._stopped = True
        if self._connecting is not None:
            self._connecting.cancel()
        self._disconnect(NotReady("this API process is stopping"))

    async def _connect(self) -> None:
        """Connect, and be welcomed; until then, try again every ``RECONNECT_S``."""
        while True:
            try:
                await self._open()
                return
            except OSError as exc:
                log.debug("engine at %s not reachable yet: %s", self.output_address, exc)
                await asyncio.sleep(RECONNECT_S)

    async def _open(self) -> None:
        self._generation += 1
        generation = self._generation
        welcomed = self._loop.create_future()
        requests_proven = self._loop.create_future()
        answers = requests = None
        try:
            answers, _ = await open_link(self._loop, self.output_address, lambda: AnswersLink(
                self, generation, links.ApiSide(self.credential, links.ANSWERS, self.identity), welcomed))
            requests, _ = await open_link(self._loop, self.input_address, lambda: RequestsLink(
                self, generation, links.ApiSide(self.credential, links.REQUESTS, self.identity), requests_proven))
            done, _ = await asyncio.wait((requests_proven, welcomed), timeout=WELCOME_TIMEOUT_S,
                                         return_when=asyncio.FIRST_EXCEPTION)
            for future in done:
                if future.exception() is not None:
                    raise future.exception()
            if len(done) < 2:
                raise asyncio.TimeoutError()
        except (OSError, asyncio.TimeoutError, links.LinkRefused) as exc:
            for future in (welcomed, requests_proven):  # a welcome or a close that comes later is nobody's news
                if future.done() and not future.cancelled():
                    future.exception()
                future.cancel()
            for transport in (answers, requests):
                if transport is not None:
                    transport.abort()
            if isinstance(exc, links.LinkRefused) and str(exc) != self._refused_by:
                log.error("the engine at %s is not believed, and is tried again until it is: %s",
                          self.output_address, exc)
                self._refused_by = str(exc)
            raise ConnectionError(f"no welcome from the engine at {self.output_address}") from exc
        self._refused_by = None
        if generation != self._generation:  # relocated meanwhile: these go to the old address
            answers.abort()
            requests.abort()
            raise ConnectionError(f"the engine moved away from {self.output_address}")
        self._answers, self._requests = answers, requests
        self._say_dropped(self.output_address)

    def _reconnect(self) -> None:
        if not self._stopped and (self._connecting is None or self._connecting.done()):
            self._connecting = self._loop.create_task(self._connect())

    def _disconnect(self, why: NotReady) -> None:
        self._generation += 1
        for transport in (self._requests, self._answers):
            if transport is not None:
                transport.abort()
        self._requests = self._answers = None
        self._outbox = None  # its requests were the connection's: they fail with it
        self.fail_all(why)

    def _went_away(self, generation: int) -> None:
        if generation != self._generation or self._answers is None or self._stopped:
            return  # old connections, or ones still opening (their opening fails and retries)
        log.warning("engine at %s went away; %d requests fail", self.output_address, len(self._pending))
        self._disconnect(NotReady(f"the engine at {self.output_address} went away (restarting?); "
                                  "retry the request"))
        self._reconnect()

    def _send(self, request: Any) -> None:
        """The requests of one turn of the event loop leave in one write at its end: one system
        call, and one wake of the engine's input thread, for all of them. A request that is the
        only one awaiting an answer leaves at once: a lone client has nothing to share the write
        with, and waiting for the turn's end would only delay it."""
        if self._requests is None:
            raise NotReady(f"the engine at {self.input_address} is not connected (restarting?); retry the request")
        try:
            data = frames.encode_frame(ENCODE_INTO, request, self.limits.request_bytes)
        except frames.FrameTooLarge as exc:  # the engine would close the link: this request fails alone
            raise TooLarge(f"{type(request).__name__}: {exc} (sdfserver/engine/links.py)") from None
        if self._outbox is None and len(self._pending) <= 1:
            self._requests.write(data)
        elif self._outbox is None:
            self._outbox = [data]
            self._loop.call_soon(self._flush_outbox)
        else:
            self._outbox.append(data)

    def _flush_outbox(self) -> None:
        outbox, self._outbox = self._outbox, None
        if outbox and self._requests is not None:
            self._requests.write(outbox[0] if len(outbox) == 1 else b"".join(outbox))

    def _arrived(self, payload: bytes) -> None:
        try:
            outputs = DECODE_OUTPUTS(payload)
        except Exception:
            log.exception("an undecodable engine output was dropped")
            return
        try:
            self._take(outputs)
        except Exception:
            log.exception("delivering engine outputs failed")


@functools.cache
def default_limits() -> links.LinkLimits:
    """The link limits of the default settings, environment ignored (tools and tests)."""
    from sdfserver.settings import Settings

    return links.LinkLimits.of(Settings.model_construct())


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
