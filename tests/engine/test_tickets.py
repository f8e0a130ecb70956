"""Tickets: a command's completion as a callback, the way the engine process's service submits."""

from __future__ import annotations

import logging
from concurrent.futures import InvalidStateError

import pytest

from sdfserver.edits import parse_edits
from sdfserver.engine import Engine
from sdfserver.engine.commands import ApplyEdits, CreateWorld
from sdfserver.engine.tickets import Ticket
from sdfserver.errors import InvalidEdit, NotReady
from sdfserver.world import WorldConfig


def test_a_ticket_calls_back_once_with_its_result_or_its_error():
    seen = []
    ticket = Ticket(lambda result, error: seen.append((result, error)))
    assert not ticket.done() and not ticket.running() and not ticket.cancelled()
    assert ticket.set_running_or_notify_cancel() and ticket.running()
    ticket.set_result(7)
    assert seen == [(7, None)] and ticket.done() and ticket.exception() is None
    with pytest.raises(InvalidStateError):
        ticket.set_exception(ValueError("late"))
    assert seen == [(7, None)]
    failed = Ticket(lambda result, error: seen.append((result, error)))
    boom = ValueError("boom")
    failed.set_exception(boom)
    assert seen[-1] == (None, boom) and failed.exception() is boom


def test_a_failing_callback_is_logged_and_does_not_reach_who_completes_the_ticket(caplog):
    def broken(result, error):
        raise RuntimeError("callback bug")

    ticket = Ticket(broken)
    with caplog.at_level(logging.ERROR, logger="sdfserver.engine"):
        ticket.set_result(1)  # does not raise
    assert ticket.done() and "callback failed" in caplog.text


def test_the_engine_answers_a_ticket_with_each_batch_version_or_its_own_error(gpu):
    engine = Engine(gpu)
    try:
        made = engine.submit(CreateWorld(WorldConfig(size=(16, 16, 16), chunk_size=8, max_distance=5)))
        engine.step()
        world_id = made.result()["id"]
        answers: dict[str, tuple] = {}

        def batch(name: str, raw: list) -> Ticket:
            return engine.submit(ApplyEdits(world_id, parse_edits(raw), raw),
                                 on_done=lambda result, error: answers.__setitem__(name, (result, error)))

        good = batch("good", [{"op": "box", "min": [1, 1, 1], "max": [4, 4, 4], "colour": 3}])
        batch("outside", [{"op": "box", "min": [5, 1, 1], "max": [4, 4, 4], "colour": 3}])  # min past max
        batch("second", [{"op": "sphere", "center": [8.0, 8.0, 8.0], "radius": 2.5, "colour": 9}])
        assert isinstance(good, Ticket) and answers == {}  # nothing before the step
        engine.step()
        assert answers["good"] == (1, None), answers
        assert answers["second"] == (2, None), answers
        assert answers["outside"][0] is None and isinstance(answers["outside"][1], InvalidEdit)
    finally:
        engine.stop()
    refused = []
    engine.submit(ApplyEdits(world_id, [], []), on_done=lambda result, error: refused.append(error))
    assert len(refused) == 1 and isinstance(refused[0], NotReady)  # a stopped engine answers at once
