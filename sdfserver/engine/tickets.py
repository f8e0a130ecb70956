"""A command's completion as a callback: what ``concurrent.futures.Future`` offers the engine
(``set_running_or_notify_cancel``, ``set_result``, ``set_exception``, ``done``), without the
condition and lock a Future makes and takes at each of those steps. The engine process's input
thread submits every request it reads, and those locks and conditions cost it more than the
rest of a batch's handling; nobody blocks on a request's completion there, its callback sends
the reply.

A ticket is completed once, by the engine thread or the log's committer; a second completion
raises ``InvalidStateError`` as a Future's would. The callback runs on the thread that completes
the ticket, and an error it raises is logged there, as a Future's callbacks' are."""

from __future__ import annotations

import logging
from concurrent.futures import InvalidStateError
from typing import Any, Callable

log = logging.getLogger("sdfserver.engine")
PENDING, RUNNING, FINISHED = 0, 1, 2
OnDone = Callable[[Any, BaseException | None], None]  # (result, None) or (None, error)


class Ticket:
    __slots__ = ("_on_done", "_state", "_exception")

    def __init__(self, on_done: OnDone):
        self._on_done = on_done
        self._state = PENDING
        self._exception: BaseException | None = None

    def set_running_or_notify_cancel(self) -> bool:
        if self._state != PENDING:
            raise InvalidStateError(f"ticket already {'running' if self._state == RUNNING else 'done'}")
        self._state = RUNNING
        return True

    def running(self) -> bool:
        return self._state == RUNNING

    def cancelled(self) -> bool:  # a ticket cannot be cancelled
        return False

    def done(self) -> bool:
        return self._state == FINISHED

    def exception(self) -> BaseException | None:
        if self._state != FINISHED:
            raise InvalidStateError("ticket not done yet")
        return self._exception

    def set_result(self, result: Any) -> None:
        self._finish(result, None)

    def set_exception(self, exception: BaseException) -> None:
        self._finish(None, exception)

    def _finish(self, result: Any, exception: BaseException | None) -> None:
        if self._state == FINISHED:
            raise InvalidStateError("ticket already done")
        self._state, self._exception = FINISHED, exception
        try:
            self._on_done(result, exception)
        except Exception:
            log.exception("a ticket's callback failed")
