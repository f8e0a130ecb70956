"""One server per port: ``sdfserver serve`` binds its listening socket once, before any engine
warms up, so that a second server on a port in use stops at once with "address already in
use". Every API process serves that one socket (the kernel hands each connection to one of
them)."""

from __future__ import annotations

import errno
import socket


def listen_once(host: str, port: int, backlog: int = 2048) -> socket.socket:
    """The server's listening socket on (host, port), or OSError (EADDRINUSE: another server or
    program has it). Port 0 picks a free one: ``getsockname()`` of the returned socket."""
    family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    sock = socket.socket(family, kind, proto)
    try:
        # a connection of an earlier server's left in TIME_WAIT does not hold the port; a
        # listening socket does (no SO_REUSEPORT: nobody may join this one)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(backlog)
    except OSError:
        sock.close()
        raise
    sock.set_inheritable(True)
    return sock


def cannot_listen(host: str, port: int, exc: OSError) -> str:
    if exc.errno == errno.EADDRINUSE:
        return (f"cannot listen on {host}:{port}: address already in use (another sdfserver or another "
                "program listens there); stop it or choose another --port")
    return f"cannot listen on {host}:{port}: {exc.strerror or exc}"
