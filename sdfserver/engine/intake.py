"""The engine's request sockets, and which thread reads them.

The input thread reads them while the engine thread steps. While the engine thread waits for
work, it reads them itself (``engine_wait``, lent to the engine as its ``idle_wait``): a request
that finds the engine idle is read, decoded and submitted by the thread that will run it, so the
input thread waking the engine thread, and the GIL passing between them, is not on its way.

The sockets change hands between requests, never during one:

- the engine thread, as it starts to wait, asks for them (``_ask``);
- the input thread gives them up after what it is reading (``_handed``) and waits for its turn;
- the engine thread gives them back before it steps, unless it had waited ``LONE_IDLE_S`` or
  more for work: requests come one at a time then, and the input thread, woken to take the
  sockets, would take the GIL from the step at its first system call and make the engine thread
  wait to be woken for it;
- the input thread takes them from a step that has kept them ``LONG_STEP_S`` (it looks that
  often while it waits for its turn), so that a long step holds up no one else's requests.

A request that arrives during either hand-over is read by the thread that holds the sockets then;
each API process's requests are read in the order they came, by one thread at a time.
"""

from __future__ import annotations

import logging
import os
import selectors
import socket
import threading
import time
from typing import Any, Callable

import msgspec

from sdfserver.engine import frames
from sdfserver.engine import messages as msg
from sdfserver.engine.lifetime import WakeFlag

log = logging.getLogger("sdfserver.engine")
IDLE_POLL_S = 0.05  # how often a waiting thread looks at whether the transport is stopping
READ_BUFFER = 1 << 20
LONE_IDLE_S = 0.0002
LONG_STEP_S = 0.005
LISTEN, ASKED, HANDED, WAKE = "listen", "asked", "handed", "wake"  # what a selector key is


class Peer:
    """One API process's connection, as one thread of the transport sees it."""

    __slots__ = ("sock", "reader", "identity", "backlog")

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.reader = frames.FrameReader()
        self.identity: bytes | None = None  # its first frame
        self.backlog = bytearray()  # answers the socket has not taken yet (output side)


class Intake:
    def __init__(self, listener: socket.socket, handle: Callable[[bytes, Any], None]):
        """``handle(identity, request)``: what each request is given to, in the order it came."""
        self.handle = handle
        self.stopping = False
        self.selector = selectors.DefaultSelector()  # the sockets: used by their holder alone
        self.selector.register(listener, selectors.EVENT_READ, LISTEN)
        self._listener = listener
        self._ask = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)  # the engine thread wants them
        self._handed = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)  # the input thread let go
        self.selector.register(self._ask, selectors.EVENT_READ, ASKED)
        self._lock = threading.Lock()
        self._asked = False
        self._engine_reads = False  # the engine thread holds the sockets
        self._kept_since: float | None = None  # it holds them through the step it is running
        self._input_turn = threading.Event()  # set while the input thread may hold them
        self._input_turn.set()
        self._wake: WakeFlag | None = None
        self._waiting: selectors.BaseSelector | None = None  # the engine thread's, while it asks
        self._wake_registered = False
        self._buffer = bytearray(READ_BUFFER)  # one holder at a time reads into it
        self._view = memoryview(self._buffer)

    def lend_to(self, wake: WakeFlag) -> Callable[[float | None], None]:
        """The engine's ``idle_wait``: reads the sockets until ``wake`` is set (work for the
        engine thread) or ``timeout_s`` passes."""
        self._wake = wake
        self._waiting = selectors.DefaultSelector()
        self._waiting.register(wake.fileno(), selectors.EVENT_READ, WAKE)
        self._waiting.register(self._handed, selectors.EVENT_READ, HANDED)
        return self.engine_wait

    def stop(self) -> None:
        self.stopping = True
        if self._wake is not None:
            self._wake.set()  # an engine thread reading the sockets gives them back

    # -- the input thread ---------------------------------------------------------------------------

    def run_input(self) -> None:
        try:
            while not self.stopping:
                if not self._input_turn.wait(LONG_STEP_S):
                    self._take_from_a_step(LONG_STEP_S)
                    continue
                self._read(self.selector.select(IDLE_POLL_S))
                if self._asked:
                    self._hand_over()
        finally:
            self._take_from_a_step(0.0)
            self._input_turn.wait(1.0)  # an engine thread reading them gives them back as it stops
            for key in list(self.selector.get_map().values()):
                if key.data not in (ASKED, WAKE):
                    key.fileobj.close()
            self.selector.close()

    def _hand_over(self) -> None:
        with self._lock:
            if not self._asked:  # the engine thread found work meanwhile
                return
            self._asked = False
            self._engine_reads = True
            self._input_turn.clear()
        os.eventfd_write(self._handed, 1)

    def _take_from_a_step(self, kept_s: float) -> None:
        with self._lock:
            if self._kept_since is None or time.monotonic() - self._kept_since < kept_s:
                return
            self._kept_since = None
            self._engine_reads = False
            self._unregister_wake()
            self._input_turn.set()

    # -- the engine thread ----------------------------------------------------------------------------

    def engine_wait(self, timeout_s: float | None) -> None:
        wake = self._wake
        if self.stopping:  # the input thread is gone
            wake.wait(timeout_s)
            return
        if wake.is_set():
            return
        entered = time.monotonic()
        deadline = None if timeout_s is None else entered + timeout_s
        with self._lock:
            self._kept_since = None
            self._asked = not self._engine_reads
        if self._asked:
            os.eventfd_write(self._ask, 1)
        try:
            while not wake.is_set() and not self.stopping:
                left = IDLE_POLL_S if deadline is None else min(IDLE_POLL_S, deadline - time.monotonic())
                if left <= 0:
                    return
                if self._engine_reads:
                    if not self._wake_registered:
                        self.selector.register(wake.fileno(), selectors.EVENT_READ, WAKE)
                        self._wake_registered = True
                    self._read(self.selector.select(left))
                elif self._waiting.select(left):
                    _drain(self._handed)  # a late notice of an earlier hand-over may come too
        finally:
            self._give_back(keep=time.monotonic() - entered >= LONE_IDLE_S and not self.stopping)

    def _give_back(self, keep: bool) -> None:
        with self._lock:
            self._asked = False
            if self._engine_reads and keep:
                self._kept_since = time.monotonic()
            elif self._engine_reads:
                self._engine_reads = False
                self._unregister_wake()
                self._input_turn.set()
        _drain(self._handed)

    def _unregister_wake(self) -> None:
        if self._wake_registered:
            self.selector.unregister(self._wake.fileno())
            self._wake_registered = False

    # -- either thread, holding the sockets -------------------------------------------------------------

    def _read(self, ready: list) -> None:
        for key, _ in ready:
            if key.data is LISTEN:
                sock, _ = self._listener.accept()
                frames.prepare(sock)
                self.selector.register(sock, selectors.EVENT_READ, Peer(sock))
            elif key.data is ASKED:
                _drain(self._ask)
            elif key.data is not WAKE:
                self._take(key.data)

    def _take(self, peer: Peer) -> None:
        try:
            size = peer.sock.recv_into(self._buffer)
        except OSError:
            size = 0
        if not size:  # the API process closed it (or went away)
            self.selector.unregister(peer.sock)
            peer.sock.close()
            return
        for payload in peer.reader.feed(self._view[:size]):
            if peer.identity is None:
                peer.identity = payload
                continue
            try:
                request = msg.REQUEST_DECODER.decode(payload)
            except (ValueError, msgspec.DecodeError) as exc:
                log.warning("an undecodable request was dropped: %s", exc)
                continue
            self.handle(peer.identity, request)


def _drain(fd: int) -> None:
    try:
        os.eventfd_read(fd)
    except BlockingIOError:
        pass
