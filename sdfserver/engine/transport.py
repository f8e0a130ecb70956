"""The input and output threads of one engine process, on stream sockets (``frames.py``).

- The input thread accepts API processes' request connections and reads them: each one first
  proves it holds the engine's credential and says its identity (``links.py``), and every later
  frame is a request, handed to ``EngineService.handle`` in the order it came. Nothing a
  connection sends is decoded before it has proven itself, so the ``Access`` a request carries
  is only ever believed from an API process of this server.
- The output thread accepts their answer connections (proof and identity again; the engine then
  welcomes it with an empty batch) and sends what the engine answered, from one queue: all that
  waited for one API process leaves as one ``Outputs`` frame, cut in several where it would pass
  the link's limit. Sockets are non-blocking: what an API process does not take at once waits in
  its backlog while the others are served.

A connection that does not prove itself within ``links.PROOF_TIMEOUT_S``, fails its proof or
announces a frame past the link's limit is closed at once, counted in
``sdfserver_engine_links_refused_total`` and logged.

A thread that completes several answers at once (the engine thread ending a step, the log's
committer acknowledging a sync's batches) does it inside ``holding()``: its answers leave together
as the block ends, from that thread itself when the output thread is idle and they are small
(``answer_frames.DIRECT_SEND_BYTES``). The output thread, woken, would first wait for the GIL that
the engine thread holds while it recomputes; the answering thread holds it already. Whoever sends
holds ``_sending``, so answers leave in the order they were queued.

Answers for an API process that is not connected wait ``UNREACHABLE_GRACE_S`` (a restarted
engine's API processes reconnecting); after that its subscriptions are dropped.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import selectors
import socket
import threading
import time
from typing import Any, Iterator

import msgspec
from prometheus_client import CollectorRegistry

from sdfserver.engine import frames, links
from sdfserver.engine import messages as msg
from sdfserver.engine.answer_frames import framed, small
from sdfserver.engine.gate import LinkGate, Peer
from sdfserver.engine.service import EngineService, SubscriptionNews
from sdfserver.threadnames import name_os_thread

log = logging.getLogger("sdfserver.engine")
IDLE_POLL_S = 0.05  # how often an idle thread looks at whether the transport is stopping
UNREACHABLE_GRACE_S = 10.0  # how long answers wait for an API process that is not connected
READ_BUFFER = 1 << 20
WELCOME = frames.frame(links.WELCOME)


class EngineTransport:
    def __init__(self, service_of, address: Any, limits: links.LinkLimits,
                 registry: CollectorRegistry | None = None):
        """``address.credential``: what every connection must prove it holds (None: Unix
        sockets only, which prove nothing). ``registry``: where the refused links are counted
        (the engine's metrics)."""
        if address.credential is None and not all(a.startswith("ipc://") for a in (address.input, address.output)):
            raise ValueError("an engine listening on TCP needs a link credential (sdfserver/engine/links.py)")
        self.outputs: collections.deque = collections.deque()
        self.service: EngineService = service_of(self.send)
        self.address = address
        self.limits = limits
        self.gate = LinkGate(address.credential, address.index, registry)
        self._stopping = False
        self._wake = os.eventfd(0, os.EFD_NONBLOCK)
        self._waiting = False  # the output thread is (about to be) waiting in select
        self._sending = threading.Lock()  # held by whichever thread sends and by the output thread's work
        self._held = threading.local()  # depth: this thread is inside holding()
        self._selector = selectors.DefaultSelector()  # the output side's
        self._input = frames.listen(address.input)
        self._output = frames.listen(address.output)
        self._output.setblocking(False)
        self._answers: dict[bytes, Peer] = {}  # output thread only
        self._unproven: set[Peer] = set()  # output thread only: answer connections not proven yet
        self._undelivered: dict[bytes, tuple[float, list[bytes]]] = {}  # client -> (since, frames)
        self._threads = [threading.Thread(target=self._read, name="sdfserver-engine-input", daemon=True),
                         threading.Thread(target=self._write, name="sdfserver-engine-output", daemon=True)]

    def start(self) -> None:
        for thread in self._threads:
            thread.start()

    def stop(self, timeout_s: float = 1.0) -> None:
        """Both threads end and close every socket (API processes see the engine go)."""
        self._stopping = True
        os.eventfd_write(self._wake, 1)
        for thread in self._threads:
            if thread.is_alive():
                thread.join(timeout_s)

    def send(self, client: bytes, item: Any) -> None:
        """Any thread: queue a Reply or a subscription's news for ``client``. Inside
        ``holding()`` it leaves as the block ends; otherwise the output thread is woken, only
        when it waits (it sets ``_waiting`` before it last looks at the queue, so either it
        sees this item or this sees it waiting)."""
        self.outputs.append((client, item))
        if not getattr(self._held, "depth", 0):
            self._wake_output()

    @contextlib.contextmanager
    def holding(self) -> Iterator[None]:
        """The answers this thread queues within the block leave together as it ends: sent by
        this thread when the output thread is idle, else handed to it."""
        held = self._held
        depth = getattr(held, "depth", 0)
        held.depth = depth + 1
        try:
            yield
        finally:
            held.depth = depth
            if not depth and self.outputs:
                if (self._waiting and not self._stopping and small(list(self.outputs))
                        and self._sending.acquire(blocking=False)):
                    try:
                        self._send_outputs()
                    except Exception:  # as in the output thread: later answers must still go
                        log.exception("sending the engine's answers failed")
                    finally:
                        self._sending.release()
                if self.outputs:
                    self._wake_output()

    def _wake_output(self) -> None:
        if self._waiting:
            self._waiting = False
            os.eventfd_write(self._wake, 1)

    # -- input -----------------------------------------------------------------------------------

    def _read(self) -> None:
        name_os_thread()
        selector = selectors.DefaultSelector()
        selector.register(self._input, selectors.EVENT_READ)
        buffer = bytearray(READ_BUFFER)
        view = memoryview(buffer)
        decode, handle = msg.REQUEST_DECODER.decode, self.service.handle
        unproven: set[Peer] = set()

        def close(peer: Peer) -> None:
            selector.unregister(peer.sock)
            peer.sock.close()
            unproven.discard(peer)

        try:
            while not self._stopping:
                for key, _ in selector.select(IDLE_POLL_S):
                    peer = key.data
                    if peer is None:
                        peer = self.gate.greet(self._input, links.REQUESTS, blocking=True)
                        if peer is not None:
                            selector.register(peer.sock, selectors.EVENT_READ, peer)
                            unproven.add(peer)
                        continue
                    space = peer.reader.space()  # the rest of a large request goes straight to its buffer
                    try:
                        size = peer.sock.recv_into(buffer if space is None else space)
                    except OSError:
                        size = 0
                    if not size:  # the API process closed it (or went away)
                        close(peer)
                        continue
                    try:
                        if space is not None:
                            payloads = peer.reader.filled(size)
                        elif peer.identity is not None:
                            payloads = peer.reader.feed(view[:size])
                        else:  # its proof alone; what follows it is read with the link's limit
                            payloads = peer.reader.feed(view[:size], most=1)
                            if payloads:
                                if not self.gate.prove(peer, payloads.pop(), peer.sock.sendall):
                                    close(peer)
                                    continue
                                unproven.discard(peer)
                                peer.reader.limit = self.limits.request_bytes
                                payloads = peer.reader.feed(b"")
                    except frames.FrameTooLarge as exc:
                        self.gate.refuse(peer, "too_large", str(exc))
                        close(peer)
                        continue
                    except OSError:  # it went away while the engine sent its proof
                        close(peer)
                        continue
                    for payload in payloads:
                        try:
                            request = decode(payload)
                        except (ValueError, msgspec.DecodeError) as exc:
                            log.warning("an undecodable request was dropped: %s", exc)
                            continue
                        handle(peer.identity, request)
                for peer in self.gate.overdue(unproven):
                    close(peer)
        finally:
            for key in list(selector.get_map().values()):
                key.fileobj.close()
            selector.close()

    # -- output ----------------------------------------------------------------------------------

    def _write(self) -> None:
        name_os_thread()
        selector = self._selector
        selector.register(self._wake, selectors.EVENT_READ, "wake")
        selector.register(self._output, selectors.EVENT_READ, "listen")
        try:
            while not self._stopping:
                try:
                    self._write_once(selector)
                except Exception:  # a bug here must not leave every later answer unsent
                    log.exception("the engine's output thread failed to send; it goes on")
        finally:
            with self._sending:
                for key in list(selector.get_map().values()):
                    if key.data != "wake":
                        key.fileobj.close()
                selector.close()  # the wake descriptor stays open: a late answer may still be queued

    def _write_once(self, selector: selectors.BaseSelector) -> None:
        """Wait for answers (or a connection, or room in a backlogged one), then send every
        answer waiting: one frame per API process."""
        self._waiting = True
        ready = selector.select(0 if self.outputs else IDLE_POLL_S)
        self._waiting = False
        with self._sending:
            for key, events in ready:
                if key.data == "wake":
                    try:
                        os.eventfd_read(self._wake)
                    except BlockingIOError:
                        pass
                elif key.data == "listen":
                    self._accept(selector)
                elif events & selectors.EVENT_WRITE:
                    self._flush(selector, key.data)
                else:
                    self._hear(selector, key.data)
            for peer in self.gate.overdue(self._unproven):
                self._lost(selector, peer)
            if self._undelivered:
                self._send_undelivered(selector)
            self._send_outputs()

    def _send_outputs(self) -> None:
        """Every answer queued, one frame per API process (with ``_sending`` held)."""
        batches: dict[bytes, list] = collections.defaultdict(list)
        news_sent: set[tuple[bytes, int]] = set()
        outputs = self.outputs
        while outputs:
            client, out = outputs.popleft()
            if isinstance(out, SubscriptionNews):
                if (client, out.number) not in news_sent:  # one update a batch holds all its news
                    news_sent.add((client, out.number))
                    update = self.service.update_for(client, out)
                    if update is not None:
                        batches[client].append(update)
            else:
                batches[client].append(out)
        for client, items in batches.items():
            for data in framed(items, self.limits.answer_bytes):
                self._deliver(self._selector, client, data)

    def _accept(self, selector: selectors.BaseSelector) -> None:
        peer = self.gate.greet(self._output, links.ANSWERS, blocking=False)
        if peer is not None:
            selector.register(peer.sock, selectors.EVENT_READ, peer)
            self._unproven.add(peer)

    def _hear(self, selector: selectors.BaseSelector, peer: Peer) -> None:
        """An answer connection is read only for its proof and identity, and for its end."""
        try:
            data = peer.sock.recv(1 << 16)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            self._lost(selector, peer)
            return
        if peer.identity is not None:
            return
        try:
            said = peer.reader.feed(data, most=1)
        except frames.FrameTooLarge as exc:
            self.gate.refuse(peer, "too_large", str(exc))
            self._lost(selector, peer)
            return
        if not said:
            return
        proof: list[bytes] = []
        if not self.gate.prove(peer, said[0], proof.append):
            self._lost(selector, peer)
            return
        self._unproven.discard(peer)
        old = self._answers.pop(peer.identity, None)
        if old is not None:
            self._lost(selector, old)
        self._answers[peer.identity] = peer
        self._deliver(selector, peer.identity, b"".join(proof) + WELCOME, first=True)

    def _lost(self, selector: selectors.BaseSelector, peer: Peer) -> None:
        """Its half-sent answers go with it: the API process failed its waiting requests. (An
        event the output thread saw before another thread lost the peer may bring it here again.)"""
        with contextlib.suppress(KeyError, ValueError):
            selector.unregister(peer.sock)
        peer.sock.close()
        self._unproven.discard(peer)
        if peer.identity is not None and self._answers.get(peer.identity) is peer:
            del self._answers[peer.identity]

    def _deliver(self, selector: selectors.BaseSelector, client: bytes, data: bytes, first: bool = False) -> None:
        if client in self._undelivered and not first:  # after what waits for it, in order
            self._undelivered[client][1].append(data)
            return
        peer = self._answers.get(client)
        if peer is None:
            self._undelivered[client] = (time.monotonic(), [data])
            return
        if peer.backlog:
            peer.backlog += data
            return
        try:
            sent = peer.sock.send(data)
        except BlockingIOError:
            sent = 0
        except OSError:
            self._lost(selector, peer)
            self._undelivered[client] = (time.monotonic(), [data])
            return
        if sent < len(data):
            peer.backlog += memoryview(data)[sent:]
            selector.modify(peer.sock, selectors.EVENT_READ | selectors.EVENT_WRITE, peer)

    def _flush(self, selector: selectors.BaseSelector, peer: Peer) -> None:
        try:
            sent = peer.sock.send(peer.backlog)
        except BlockingIOError:
            return
        except OSError:
            self._lost(selector, peer)
            return
        del peer.backlog[:sent]
        if not peer.backlog:
            selector.modify(peer.sock, selectors.EVENT_READ, peer)

    def _send_undelivered(self, selector: selectors.BaseSelector) -> None:
        """Answers for an API process not connected: not yet again, when this engine was just
        restarted (a cluster's engine actor) and the API process is reconnecting, or never
        again, when it is gone (its subscriptions are dropped after the grace)."""
        for client, (since, waiting) in list(self._undelivered.items()):
            if client in self._answers:
                del self._undelivered[client]
                for data in waiting:
                    self._deliver(selector, client, data)
            elif time.monotonic() - since > UNREACHABLE_GRACE_S:
                del self._undelivered[client]
                self.service.forget(client)
