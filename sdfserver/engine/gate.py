"""The door of an engine's transport: each new connection is greeted with its challenge, then
proven or refused (``links.py``). A refused connection is counted in
``sdfserver_engine_links_refused_total`` by reason and logged, at most once a second with the
others summed into the next line, so that a flood of them cannot flood the log."""

from __future__ import annotations

import logging
import socket
import time
from typing import Any

from prometheus_client import CollectorRegistry, Counter

from sdfserver.engine import frames, links

log = logging.getLogger("sdfserver.engine")
REFUSALS_LOGGED_EVERY_S = 1.0


class Peer:
    """One API process's connection, as one thread of the transport sees it."""

    __slots__ = ("sock", "name", "reader", "proof", "deadline", "identity", "backlog")

    def __init__(self, sock: socket.socket, name: str, proof: links.EngineSide):
        self.sock, self.name, self.proof = sock, name, proof
        self.reader = frames.FrameReader(links.HELLO_BYTES)  # until it has proven itself
        self.deadline = time.monotonic() + links.PROOF_TIMEOUT_S
        self.identity: bytes | None = None  # known once it has proven itself
        self.backlog = bytearray()  # answers the socket has not taken yet (output side)


class LinkGate:
    """The proofs of one engine's connections (both threads of its transport use it)."""

    def __init__(self, credential: bytes | None, index: int, registry: CollectorRegistry | None):
        self.credential, self.index = credential, index
        self.refused = Counter("sdfserver_engine_links_refused", "Connections to the engine closed before it "
                               "read them further, by reason: a failed proof (credential, identity), "
                               f"no proof in {links.PROOF_TIMEOUT_S:g} s (silent), a frame past the link's limit "
                               "(too_large).", ["reason"],
                               registry=registry if registry is not None else CollectorRegistry())
        self._logged = (float("-inf"), 0)  # when a refusal was last logged, and how many since

    def greet(self, listener: socket.socket, role: bytes, blocking: bool) -> Peer | None:
        """A new connection, its proof begun (the engine's challenge sent); None if it went away."""
        try:
            sock, where = listener.accept()
        except BlockingIOError:
            return None
        peer = Peer(sock, peer_name(sock.family, where), links.EngineSide(self.credential, role))
        frames.prepare(sock)
        try:
            sock.sendall(peer.proof.opening())  # a few dozen bytes into an empty socket buffer
        except OSError:
            sock.close()
            return None
        sock.setblocking(blocking)
        return peer

    def prove(self, peer: Peer, hello: bytes, send: Any) -> bool:
        """Whether ``hello`` proves ``peer``: its identity set and the engine's proof sent with
        ``send``; one that fails is counted and logged, for the caller to close."""
        try:
            identity, reply = peer.proof.heard(hello)
        except links.LinkRefused as exc:
            self.refuse(peer, exc.reason, str(exc))
            return False
        if reply:
            send(reply)
        peer.identity = identity
        return True

    def overdue(self, unproven: set[Peer]) -> list[Peer]:
        """The connections past their proof's deadline, counted and logged, for the caller to close."""
        now = time.monotonic()
        late = [peer for peer in unproven if now > peer.deadline]
        for peer in late:
            self.refuse(peer, "silent", f"no proof in {links.PROOF_TIMEOUT_S:g} s")
        return late

    def refuse(self, peer: Peer, reason: str, why: str) -> None:
        """Count it and say so (the line waits when one was said less than a second ago)."""
        self.refused.labels(reason).inc()
        last, unlogged = self._logged
        now = time.monotonic()
        if now - last < REFUSALS_LOGGED_EVERY_S:
            self._logged = (last, unlogged + 1)
            return
        more = f" ({unlogged} more refused since the last such line)" if unlogged else ""
        log.warning("engine %d refused a connection from %s (%s): %s; closed before anything it sent was read%s",
                    self.index, peer.name, reason, why, more)
        self._logged = (now, 0)


def peer_name(family: int, where: Any) -> str:
    if family in (socket.AF_INET, socket.AF_INET6):
        return f"{where[0]}:{where[1]}"
    return "a Unix socket"
