"""One server per port: ``sdfserver serve`` takes its port before the engine warms up, so a
second server on a port in use stops at once with "address already in use", with fronts or
without.

The fronts share the port through ``SO_REUSEPORT``, which lets any socket of the same user
that sets it join them. So the port is first tried with a plain bind, which fails on any
socket listening there or held by another server; then it is held, for the server's life, by
a bound, non-listening ``SO_REUSEPORT`` socket without ``SO_REUSEADDR``. The fronts (or the one
listener without fronts, ``listener``) join it; another server's plain bind fails on it.
"""

from __future__ import annotations

import errno
import logging
import socket

import uvicorn

from sdfserver.api import link

log = logging.getLogger("sdfserver")


def hold_port(host: str, port: int) -> socket.socket:
    """Take (host, port) for this server or raise OSError (EADDRINUSE: another server or
    program has it). Port 0 picks a free one: ``getsockname()`` of the returned socket."""
    family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    with socket.socket(family, kind, proto) as probe:
        # a connection of an earlier server's left in TIME_WAIT does not hold the port
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        probe.bind(address)
        address = probe.getsockname()
    held = socket.socket(family, kind, proto)
    held.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    try:
        held.bind(address)
    except OSError as exc:
        if exc.errno != errno.EADDRINUSE:
            held.close()
            raise
        # What the probe passed and this bind did not: a connection in TIME_WAIT from a socket
        # without SO_REUSEPORT (another program's, on this port lately). Held as the fronts bind.
        held.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            held.bind(address)
        except OSError:
            held.close()
            raise
    return held


def listener(held: socket.socket) -> socket.socket:
    """The listening socket of a server without fronts, on the port ``held`` holds."""
    host, port = held.getsockname()[:2]
    return link.reuseport_socket(host, port)


class OneProcessServer(uvicorn.Server):
    """uvicorn's server on the ``listener`` it is given, saying where it listens (uvicorn
    does not, given sockets)."""

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets=sockets)
        if self.started and sockets:
            host, port = sockets[0].getsockname()[:2]
            log.info("listening on http://%s:%d", host, port)


def cannot_listen(host: str, port: int, exc: OSError) -> str:
    if exc.errno == errno.EADDRINUSE:
        return (f"cannot listen on {host}:{port}: address already in use (another sdfserver or another "
                "program listens there); stop it or choose another --port")
    return f"cannot listen on {host}:{port}: {exc.strerror or exc}"
