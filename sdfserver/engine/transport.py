"""The input and output threads of one engine process, on stream sockets (``frames.py``).

- The input thread accepts API processes' request connections and reads them: each one's first
  frame is its identity, every later frame a request, handed to ``EngineService.handle`` in
  the order it came.
- The output thread accepts their answer connections (the first frame, again, the identity;
  the engine welcomes it with an empty batch) and sends what the engine answered, from one
  queue: all that waited for one API process leaves as one ``Outputs`` frame. Sockets are
  non-blocking: what an API process does not take at once waits in its backlog while the
  others are served.

A thread that completes several answers at once (the engine thread ending a step, the log's
committer acknowledging a sync's batches) does it inside ``holding()``: its answers leave together
as the block ends, from that thread itself when the output thread is idle and they are small
(``DIRECT_SEND_BYTES``). The output thread, woken, would first wait for the GIL that the engine
thread holds while it recomputes; the answering thread holds it already. Whoever sends holds
``_sending``, so answers leave in the order they were queued.

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

from sdfserver.engine import frames
from sdfserver.engine import messages as msg
from sdfserver.engine.service import EngineService, SubscriptionNews

log = logging.getLogger("sdfserver.engine")
IDLE_POLL_S = 0.05  # how often an idle thread looks at whether the transport is stopping
UNREACHABLE_GRACE_S = 10.0  # how long answers wait for an API process that is not connected
READ_BUFFER = 1 << 20
# Answers up to this many bytes leave from the thread that completes them (holding()); larger
# ones (whole fields, frames) go to the output thread: copying them into a socket would hold up
# the engine thread's next step.
DIRECT_SEND_BYTES = 1 << 16
WELCOME = frames.frame(msg.REQUEST_ENCODER.encode(msg.Outputs([])))


class Peer:
    """One API process's connection, as one thread of the transport sees it."""

    __slots__ = ("sock", "reader", "identity", "backlog")

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.reader = frames.FrameReader()
        self.identity: bytes | None = None  # its first frame
        self.backlog = bytearray()  # answers the socket has not taken yet (output side)


class EngineTransport:
    def __init__(self, service_of, address: Any):
        self.outputs: collections.deque = collections.deque()
        self.service: EngineService = service_of(self.send)
        self.address = address
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
        selector = selectors.DefaultSelector()
        selector.register(self._input, selectors.EVENT_READ)
        buffer = bytearray(READ_BUFFER)
        view = memoryview(buffer)
        decode, handle = msg.REQUEST_DECODER.decode, self.service.handle
        try:
            while not self._stopping:
                for key, _ in selector.select(IDLE_POLL_S):
                    peer = key.data
                    if peer is None:
                        sock, _ = self._input.accept()
                        frames.prepare(sock)
                        selector.register(sock, selectors.EVENT_READ, Peer(sock))
                        continue
                    space = peer.reader.space()  # the rest of a large request goes straight to its buffer
                    try:
                        size = peer.sock.recv_into(buffer if space is None else space)
                    except OSError:
                        size = 0
                    if not size:  # the API process closed it (or went away)
                        selector.unregister(peer.sock)
                        peer.sock.close()
                        continue
                    payloads = peer.reader.feed(view[:size]) if space is None else peer.reader.filled(size)
                    for payload in payloads:
                        if peer.identity is None:
                            peer.identity = payload
                            continue
                        try:
                            request = decode(payload)
                        except (ValueError, msgspec.DecodeError) as exc:
                            log.warning("an undecodable request was dropped: %s", exc)
                            continue
                        handle(peer.identity, request)
        finally:
            for key in list(selector.get_map().values()):
                key.fileobj.close()
            selector.close()

    # -- output ----------------------------------------------------------------------------------

    def _write(self) -> None:
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
            self._deliver(self._selector, client, framed(items))

    def _accept(self, selector: selectors.BaseSelector) -> None:
        try:
            sock, _ = self._output.accept()
        except BlockingIOError:
            return
        frames.prepare(sock)
        sock.setblocking(False)
        selector.register(sock, selectors.EVENT_READ, Peer(sock))

    def _hear(self, selector: selectors.BaseSelector, peer: Peer) -> None:
        """An answer connection is read only for its identity, and for its end."""
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
        said = peer.reader.feed(data)
        if said:
            peer.identity = said[0]
            old = self._answers.pop(peer.identity, None)
            if old is not None:
                self._lost(selector, old)
            self._answers[peer.identity] = peer
            self._deliver(selector, peer.identity, WELCOME, first=True)

    def _lost(self, selector: selectors.BaseSelector, peer: Peer) -> None:
        """Its half-sent answers go with it: the API process failed its waiting requests. (An
        event the output thread saw before another thread lost the peer may bring it here again.)"""
        with contextlib.suppress(KeyError, ValueError):
            selector.unregister(peer.sock)
        peer.sock.close()
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


def small(outputs: list[tuple[bytes, Any]]) -> bool:
    """Whether these answers carry at most DIRECT_SEND_BYTES of arrays and byte strings (a
    subscription's news counts as large: its chunks are taken as it is sent)."""
    carried = 0
    for _, item in outputs:
        if not isinstance(item, msg.Reply):
            return False
        result = item.result
        if isinstance(result, msg.ReadResult):
            carried += len(result.array.data)
        elif isinstance(result, msg.Frame):
            carried += len(result.pixels.data)
        elif isinstance(result, msg.QueryResult):
            carried += sum(len(a.data) for a in result.arrays.values())
        elif isinstance(result, (bytes, str)):
            carried += len(result)
    return carried <= DIRECT_SEND_BYTES


def framed(items: list[Any]) -> bytes | bytearray:
    """One API process's batch of outputs as one frame (``encoded`` where one cannot be encoded)."""
    try:
        return frames.encode_frame(msg.REQUEST_ENCODER.encode_into, msg.Outputs(items))
    except (TypeError, ValueError, OverflowError, msgspec.EncodeError):
        return frames.frame(encoded(items))


def encoded(items: list[Any]) -> bytes:
    """One API process's batch of outputs; an answer that cannot be encoded (a bug) is replaced
    by its failure, so that its request is answered and the others still go."""
    try:
        return msg.REQUEST_ENCODER.encode(msg.Outputs(items))
    except (TypeError, ValueError, OverflowError, msgspec.EncodeError):
        kept = []
        for item in items:
            try:
                msg.REQUEST_ENCODER.encode(item)
                kept.append(item)
            except (TypeError, ValueError, OverflowError, msgspec.EncodeError) as exc:
                log.exception("an engine answer could not be encoded", exc_info=exc)
                if isinstance(item, msg.Reply):
                    kept.append(msg.Reply(item.id, None, msg.failure_of(exc)))
        return msg.REQUEST_ENCODER.encode(msg.Outputs(kept))
