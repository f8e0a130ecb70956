"""Rounds of deliveries: a thread that completes many requests at once (the engine at the end
of a step, the log committer after a sync) opens a round, and a receiver that sends each
result on (a front's link) may hold what it sends until the round ends, then send it together:
one write on the link for a step's many replies instead of one each.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Any, Iterator, Protocol

_local = threading.local()


class Receiver(Protocol):
    def send_held(self, items: list[Any]) -> None: ...


@contextlib.contextmanager
def delivery_round() -> Iterator[None]:
    if getattr(_local, "held", None) is not None:  # within a round already: that one sends
        yield
        return
    held: dict[Receiver, list[Any]] = {}
    _local.held = held
    try:
        yield
    finally:
        _local.held = None
        for receiver, items in held.items():
            receiver.send_held(items)


def held_for(receiver: Receiver) -> list[Any] | None:
    """The list to hold ``receiver``'s items in until this thread's round ends; None outside a round."""
    held = getattr(_local, "held", None)
    if held is None:
        return None
    items = held.get(receiver)
    if items is None:
        items = held[receiver] = []
    return items
