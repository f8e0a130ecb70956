"""One API process: uvicorn and the FastAPI app on the listening socket the launcher bound,
with an ``EngineClient`` for each engine process. API processes are identical and hold no
device state; the kernel hands each new connection to one of them."""

from __future__ import annotations

import socket
from typing import Any, Sequence

import uvicorn

from sdfserver.api.app import create_app
from sdfserver.api.connections import uvicorn_options
from sdfserver.api.engine_client import EngineClient
from sdfserver.api.hot import HotRoutes
from sdfserver.engine.proc import EngineAddress, die_with_parent
from sdfserver.settings import Settings, worker_count


def worker_main(settings: Settings, sock: socket.socket, engines: Sequence[EngineAddress], log_config: Any,
                addresses_file: str | None = None) -> int:
    """The API process's body (after fork); its exit status. ``addresses_file``: where a
    cluster's engines' addresses are kept (an engine restarted elsewhere is followed)."""
    die_with_parent()
    clients = [EngineClient(e.input, e.output) for e in engines]
    app = create_app(settings, clients=clients, freeze_gc=True, addresses_file=addresses_file)
    config = uvicorn.Config(HotRoutes(app), log_config=log_config, log_level=settings.log_level,
                            access_log=settings.access_log, timeout_graceful_shutdown=5, lifespan="on",
                            **uvicorn_options(settings, worker_count(settings)))
    server = uvicorn.Server(config)
    server.run(sockets=[sock])
    return 0 if server.started else 3  # uvicorn's start-up failure status, as uvicorn.run exits with
