"""One server per port: ``sdfserver serve`` binds its listening socket once, before any engine
warms up, so that a second server on a port in use stops at once with "address already in
use". Every API process serves that one socket (the kernel hands each connection to one of
them), accepting from it with its own ``Listener``."""

from __future__ import annotations

import asyncio
import errno
import logging
import socket
from typing import Any, Callable

from sdfserver.api.connections import ConnectionLimits, descriptor_limit
from sdfserver.api.counts import SharedCounts, ThrottledLog

log = logging.getLogger("sdfserver.connections")
# accept() failures that leave the connection waiting: the process (or the system) is out of them
OUT_OF_RESOURCES = {errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM}
ACCEPT_BATCH = 16  # connections taken at one wake-up: each holds a descriptor until the loop runs again
RETRY_S = 0.5  # the pause in accepting after running out: the socket stays readable meanwhile
REFUSAL_TEXT = b"this server holds as many connections as it may; try again later"
REFUSAL = (b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: text/plain; charset=utf-8\r\n"
           b"content-length: %d\r\nretry-after: 1\r\nconnection: close\r\n\r\n%s" % (len(REFUSAL_TEXT), REFUSAL_TEXT))


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


class Listener:
    """This API process's accept loop on the shared listening socket, in place of the event
    loop's own. uvloop (libuv) meets a process out of file descriptors by accepting the waiting
    connections and closing them unseen, and on other accept errors closes its listener for good
    without a word. Here:

    - a connection past ``limits.max_connections`` (this process's share, or what its descriptor
      limit leaves room for) is answered 503 and closed before the loop sees it, so that its
      descriptor is free at once; counted by reason in ``counts`` and logged, throttled;
    - an accept that fails for want of descriptors or memory is counted, logged (throttled) and
      tried again after ``RETRY_S``, the connection left in the backlog, where another API
      process may take it;
    - every other connection goes to the loop's ``connect_accepted_socket``.

    It has the ``close`` and ``wait_closed`` of the ``asyncio.Server`` uvicorn would have made
    (``worker.ApiServer``)."""

    def __init__(self, sock: socket.socket, protocol_factory: Callable[[], asyncio.Protocol],
                 connections: set[Any], limits: ConnectionLimits, counts: SharedCounts):
        self.loop = asyncio.get_running_loop()
        self.sock = sock
        self.protocol_factory = protocol_factory
        self.connections = connections  # uvicorn's: every connection this process serves
        self.limits = limits
        self.counts = counts
        self.failures = ThrottledLog(log)
        self.refusals = ThrottledLog(log)
        self.connecting: set[asyncio.Task[Any]] = set()
        self.retry: asyncio.TimerHandle | None = None
        self.closed = False
        sock.setblocking(False)
        self.loop.add_reader(sock.fileno(), self.accept)

    def accept(self) -> None:
        for _ in range(ACCEPT_BATCH):
            try:
                conn, _ = self.sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except ConnectionAbortedError:  # the client left before it was taken
                continue
            except OSError as exc:
                if exc.errno in OUT_OF_RESOURCES:
                    self.pause(exc)
                else:  # a network error of that one connection (accept(2)): the next is taken next time
                    self.failures.warning("accept() on the listening socket failed: %s", exc)
                return
            if len(self.connections) + len(self.connecting) >= self.limits.max_connections:
                self.refuse(conn)
            else:
                self.hand_over(conn)

    def refuse(self, conn: socket.socket) -> None:
        held = len(self.connections) + len(self.connecting)
        if self.limits.capped_by_descriptors:
            self.counts.add("refused_descriptors")
            self.refusals.warning("refusing connections with 503: this API process holds %d, as many as its "
                                  "file-descriptor limit (%s) leaves room for; raise LimitNOFILE (ulimit -n)",
                                  held, descriptor_limit())
        else:
            self.counts.add("refused_max_connections")
            self.refusals.warning("refusing connections with 503: this API process holds %d, its share of "
                                  "max_connections", held)
        try:
            conn.send(REFUSAL)  # a fresh socket's buffer takes it whole
        except OSError:  # the client is gone already: there is no one to tell
            pass
        conn.close()

    def hand_over(self, conn: socket.socket) -> None:
        task = self.loop.create_task(self.loop.connect_accepted_socket(self.protocol_factory, conn))
        self.connecting.add(task)
        task.add_done_callback(self.connected)

    def connected(self, task: asyncio.Task[Any]) -> None:
        self.connecting.discard(task)
        if not task.cancelled() and task.exception() is not None:  # the loop closed the socket
            self.failures.warning("an accepted connection could not be served: %s", task.exception())

    def pause(self, exc: OSError) -> None:
        self.counts.add("accept_failures")
        self.failures.warning("cannot accept connections: %s (this API process's file-descriptor limit is %s); "
                              "they wait in the listening socket's backlog, tried again every %g s",
                              exc.strerror or exc, descriptor_limit() or "unlimited", RETRY_S)
        self.loop.remove_reader(self.sock.fileno())
        self.retry = self.loop.call_later(RETRY_S, self.resume)

    def resume(self) -> None:
        self.retry = None
        if not self.closed:
            self.loop.add_reader(self.sock.fileno(), self.accept)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self.retry is not None:
            self.retry.cancel()
        else:
            self.loop.remove_reader(self.sock.fileno())

    async def wait_closed(self) -> None:
        await asyncio.gather(*self.connecting, return_exceptions=True)
