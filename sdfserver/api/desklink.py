"""The server process's end of a front's link, served by threads instead of the event loop.

A reader thread takes the front's messages as they arrive (engine commands, above all) and
hands them on; a reply leaves from the thread that completes it (the engine's or the log
committer's) straight onto the socket. Through the event loop, every command and every reply
waited for the loop to be scheduled and to win the GIL, and under many clients the loop held a
third of the server process's GIL time doing that.

The framing is ``link.py``'s (length-prefixed pickles), so the front's end is the same
``LinkProtocol``. A small reply goes out at once when the socket takes it whole, or, sent in a
round of deliveries (``sdfserver/delivery.py``: an engine step's answers, a log sync's
acknowledgements), with the rest of the round in one frame at its end. Anything else
(a large read, a reply behind one still being written, a full socket) goes to a writer thread
in order, so frames never interleave and the completing thread never waits for the front.
"""

from __future__ import annotations

import collections
import logging
import socket
import threading
from typing import Any, Callable

from sdfserver import delivery
from sdfserver.api.link import frame, take_frames

log = logging.getLogger("sdfserver.fronts")
READ_BYTES = 256 << 10


class DeskLink:
    def __init__(self, sock: socket.socket, on_message: Callable[[Any], None], name: str,
                 on_lost: Callable[[], None] = lambda: None):
        sock.setblocking(True)
        self.sock, self.on_message, self.on_lost = sock, on_message, on_lost
        self._cond = threading.Condition()
        self._backlog: collections.deque[bytes | memoryview | tuple[Any]] = collections.deque()
        self._writing = False  # the writer thread has taken a frame and is sending it
        self.closed = False
        self._threads = [threading.Thread(target=self._read, name=f"{name}-in", daemon=True),
                         threading.Thread(target=self._write, name=f"{name}-out", daemon=True)]

    def start(self) -> None:
        for thread in self._threads:
            thread.start()

    def send(self, message: Any, small: bool = True) -> None:
        """Send ``message`` from any thread. A small one is pickled here and written now if the
        socket takes it whole; a large one (``small=False``) is pickled by the writer thread."""
        if small:
            held = delivery.held_for(self)
            if held is not None:  # a round of replies (an engine step's, a sync's): one frame at its end
                held.append(message)
                return
        self._send(frame([message]) if small else (message,))

    def send_held(self, messages: list[Any]) -> None:
        self._send(frame(messages))

    def _send(self, data: bytes | memoryview | tuple[Any]) -> None:
        small = not isinstance(data, tuple)
        with self._cond:
            if self.closed:
                return
            if small and not self._writing and not self._backlog:
                try:
                    sent = self.sock.send(data, socket.MSG_DONTWAIT)  # type: ignore[arg-type]
                except BlockingIOError:
                    sent = 0
                except OSError:
                    return  # the front is gone; the reader sees it and reports the loss
                if sent == len(data):  # type: ignore[arg-type]
                    return
                data = memoryview(data)[sent:]  # type: ignore[arg-type]
            self._backlog.append(data)
            self._cond.notify()

    def _write(self) -> None:
        while True:
            with self._cond:
                while not self._backlog and not self.closed:
                    self._writing = False
                    self._cond.wait()
                if self.closed:
                    return
                item = self._backlog.popleft()
                self._writing = True  # until the backlog is empty: later frames queue behind
            try:
                self.sock.sendall(frame([item[0]]) if isinstance(item, tuple) else item)
            except OSError:
                return

    def _read(self) -> None:
        buffer = bytearray()
        try:
            while True:
                data = self.sock.recv(READ_BYTES)
                if not data:
                    break
                buffer += data
                take_frames(buffer, self.on_message)
        except OSError:
            pass
        except Exception:
            log.exception("a front's link failed")
        self.close()
        self.on_lost()

    def close(self) -> None:
        with self._cond:
            if self.closed:
                return
            self.closed = True
            self._cond.notify_all()
        try:
            self.sock.shutdown(socket.SHUT_RDWR)  # wakes the reader; it closes nothing itself
        except OSError:
            pass

    def join(self, timeout_s: float = 5.0) -> None:
        """After ``close``: wait for both threads, then release the socket."""
        for thread in self._threads:
            if thread is not threading.current_thread() and thread.is_alive():
                thread.join(timeout_s)
        self.sock.close()
