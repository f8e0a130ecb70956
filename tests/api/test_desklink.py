"""The server's end of a front link (``desklink.DeskLink``): messages in on its reader thread,
replies out from any thread, whole frames in every case (a full socket, large replies, many
threads at once), and a lost front reported once."""

from __future__ import annotations

import pickle
import queue
import random
import socket
import threading

import numpy as np
import pytest

from sdfserver.delivery import delivery_round
from sdfserver.api.desklink import DeskLink
from sdfserver.api.link import HEADER, frame


def read_frames(sock: socket.socket, count: int) -> list:
    """The front's side, blocking: ``count`` messages in link.py's framing."""
    messages, buffer = [], bytearray()
    while len(messages) < count:
        data = sock.recv(1 << 16)
        assert data, f"the link closed after {len(messages)} of {count} messages"
        buffer += data
        while len(buffer) >= HEADER.size:
            (size,) = HEADER.unpack_from(buffer)
            if len(buffer) < HEADER.size + size:
                break
            messages += pickle.loads(bytes(buffer[HEADER.size:HEADER.size + size]))
            del buffer[:HEADER.size + size]
    return messages


def make_link(on_message=lambda message: None, on_lost=lambda: None):
    here, there = socket.socketpair()
    link = DeskLink(here, on_message, "test", on_lost)
    link.start()
    return link, there


def test_messages_in_arrive_in_order_on_the_reader_thread():
    received: queue.Queue = queue.Queue()
    link, front = make_link(lambda m: received.put((m, threading.current_thread().name)))
    big = np.arange(300_000, dtype=np.uint16)
    # two frames of several messages and one of one, the large one split across recv calls
    front.sendall(frame([("call", 0, 0), ("call", 1, 1)]) + frame([("call", 2, 2), ("call", 3, big)])
                  + frame([("call", i, i) for i in (4, 5)]))
    got = [received.get(timeout=5) for _ in range(6)]
    assert [m[1] for m, _ in got] == list(range(6))
    assert np.array_equal(got[3][0][2], big)
    assert {name for _, name in got} == {"test-in"}
    link.close()
    link.join()
    front.close()


def test_replies_stay_whole_when_the_front_is_slow_and_many_threads_send():
    link, front = make_link()
    rng = random.Random()
    seed = rng.randrange(1 << 30)
    sizes = random.Random(seed).choices([0, 10, 100_000, 600_000], k=200)  # some over a socket buffer
    expected = {}

    def sender(indices: list[int]) -> None:
        for i in indices:
            payload = np.full(sizes[i], i % 251, dtype=np.uint8)
            expected[i] = payload
            link.send(("reply", i, True, payload), small=sizes[i] < 50_000)

    # nobody reads yet: the socket fills, and sends after that must queue behind, in whole frames
    threads = [threading.Thread(target=sender, args=(list(range(k, 200, 4)),)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    messages = read_frames(front, 200)
    assert sorted(m[1] for m in messages) == list(range(200)), f"seed {seed}"
    for _, i, ok, payload in messages:
        assert ok and np.array_equal(payload, expected[i]), f"seed {seed}: reply {i}"
    link.close()
    link.join()
    front.close()


def test_a_lost_front_is_reported_once_and_later_sends_are_dropped():
    lost = threading.Event()
    calls = []

    def on_lost() -> None:
        calls.append(1)
        lost.set()

    link, front = make_link(on_lost=on_lost)
    front.close()
    assert lost.wait(5)
    assert link.closed
    link.send(("reply", 1, True, 7))  # the front is gone: nothing to raise in the engine's thread
    link.send(("reply", 2, True, np.zeros(1 << 20, np.uint8)), small=False)
    link.close()
    link.join()
    assert calls == [1]


def test_replies_in_a_delivery_round_leave_together_at_its_end():
    link, front = make_link()
    front.settimeout(0.2)
    with delivery_round():
        with delivery_round():  # a nested round sends nothing of its own
            for i in range(5):
                link.send(("reply", i, True, i))
        link.send(("reply", 5, True, np.zeros(100_000, np.uint8)), small=False)  # large: not held
        assert read_frames(front, 1)[0][1] == 5
        with pytest.raises(TimeoutError):
            front.recv(1)
    front.settimeout(5)
    (size,) = HEADER.unpack(front.recv(HEADER.size, socket.MSG_WAITALL))
    one_frame = pickle.loads(front.recv(size, socket.MSG_WAITALL))  # the round's five, together
    assert [m[1] for m in one_frame] == list(range(5))
    link.close()
    link.join()
    front.close()
