"""One API process: uvicorn and the FastAPI app on the listening socket the launcher bound,
with an ``EngineClient`` for each engine process. API processes are identical and hold no
device state; the kernel hands each new connection to one of them."""

from __future__ import annotations

import asyncio
import socket
from typing import Any, Sequence

import uvicorn

from sdfserver.api.app import create_app
from sdfserver.api.connections import uvicorn_options
from sdfserver.api.counts import SharedCounts
from sdfserver.api.engine_client import EngineClient
from sdfserver.api.hot import HotRoutes
from sdfserver.api.port import Listener
from sdfserver.engine.links import LinkLimits
from sdfserver.engine.proc import EngineAddress, die_with_parent
from sdfserver.errors import NotReady
from sdfserver.settings import Settings, worker_count

GRACEFUL_STOP_S = 5.0  # how long a stopping API process lets requests in flight finish
# Requests still waiting for an engine this long before the graceful stop ends are answered 503:
# uvicorn then cancels what is left, and a cancelled request gets no answer at all.
ANSWER_BEFORE_STOP_S = 0.5


class ApiServer(uvicorn.Server):
    """uvicorn's server, accepting connections with its own ``port.Listener`` (which says when the
    process runs out of file descriptors), and whose graceful stop answers the requests still
    waiting for an engine (one held by a long step) with 503 ``not_ready`` before it gives up on
    them."""

    def __init__(self, config: uvicorn.Config, clients: Sequence[EngineClient], counts: SharedCounts):
        super().__init__(config)
        self.clients = clients
        self.counts = counts

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets=[])  # the lifespan, and no server of the loop's own
        if not self.started:
            return

        def protocol() -> asyncio.Protocol:  # as uvicorn's startup makes each connection's
            return self.config.http_protocol_class(config=self.config, server_state=self.server_state,
                                                   app_state=self.lifespan.state)

        limits = self.config.http_protocol_class.limits
        self.servers = [Listener(sock, protocol, self.server_state.connections, limits, self.counts)
                        for sock in sockets or []]

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        grace = self.config.timeout_graceful_shutdown or GRACEFUL_STOP_S
        timer = asyncio.get_running_loop().call_later(max(0.0, grace - ANSWER_BEFORE_STOP_S), self.cut_off)
        try:
            await super().shutdown(sockets)
        finally:
            timer.cancel()

    def cut_off(self) -> None:
        for client in self.clients:
            client.fail_all(NotReady("the server is stopping; retry the request"))


def worker_main(settings: Settings, sock: socket.socket, engines: Sequence[EngineAddress], log_config: Any,
                addresses_file: str | None = None, counts: SharedCounts | None = None) -> int:
    """The API process's body (after fork); its exit status. ``addresses_file``: where a
    cluster's engines' addresses are kept (an engine restarted elsewhere is followed);
    ``counts``: this process's row of the API processes' shared connection counts."""
    counts = counts if counts is not None else SharedCounts()
    die_with_parent()
    limits = LinkLimits.of(settings)
    clients = [EngineClient(e.input, e.output, e.credential, limits) for e in engines]
    app = create_app(settings, clients=clients, freeze_gc=True, addresses_file=addresses_file, counts=counts)
    config = uvicorn.Config(HotRoutes(app), log_config=log_config, log_level=settings.log_level,
                            access_log=settings.access_log, timeout_graceful_shutdown=GRACEFUL_STOP_S, lifespan="on",
                            **uvicorn_options(settings, worker_count(settings), counts))
    server = ApiServer(config, clients, counts)
    server.run(sockets=[sock])
    return 0 if server.started else 3  # uvicorn's start-up failure status, as uvicorn.run exits with
