"""The engine's stream transport with a real ``EngineClient`` on a real event loop: frames cut
anywhere, answers larger than a socket takes at once, an engine that goes away and comes back,
an API process that goes away."""

from __future__ import annotations

import asyncio
import random
import tempfile
import threading
import time

import pytest

from sdfserver.api.engine_client import EngineClient, default_limits
from sdfserver.engine import frames
from sdfserver.engine.answer_frames import DIRECT_SEND_BYTES
from sdfserver.engine import messages as msg
from sdfserver.engine import transport as transport_module
from sdfserver.engine.proc import EngineAddress
from sdfserver.engine.transport import EngineTransport
from sdfserver.errors import NotReady


def test_frames_cut_anywhere_come_back_whole():
    rng = random.Random()
    payloads = [rng.randbytes(rng.choice([0, 1, 7, 300, 70_000, 400_000])) for _ in range(40)]
    stream = b"".join(frames.frame(p) for p in payloads)
    reader, out, at = frames.FrameReader(), [], 0
    while at < len(stream):
        step = rng.choice([1, 3, 4, 5, 1000, 65_536, 300_000])
        out += reader.feed(stream[at:at + step])
        at += step
    assert out == payloads


def test_frames_read_into_their_own_buffers_come_back_whole():
    """As a socket reads them: into ``space()`` while a large frame is being gathered (at most
    what it has room for), else into a buffer of its own that is fed."""
    rng = random.Random()
    payloads = [rng.randbytes(rng.choice([0, 1, 7, 300, 70_000, 400_000, 2_000_000])) for _ in range(40)]
    stream = memoryview(b"".join(frames.frame(p) for p in payloads))
    reader, out, at = frames.FrameReader(), [], 0
    while at < len(stream):
        step = rng.choice([1, 3, 4, 5, 1000, 65_536, 300_000, 1 << 22])
        space = reader.space()
        if space is None:
            out += reader.feed(stream[at:at + step])
            at += step
        else:
            size = min(step, len(space), len(stream) - at)
            space[:size] = stream[at:at + size]
            out += reader.filled(size)
            at += size
    assert out == payloads


class Service:
    """Answers Status with the size of answer asked for (in its id), or holds it unanswered."""

    def __init__(self, send):
        self.send = send
        self.forgotten: list[bytes] = []
        self.held: list[tuple[bytes, int]] = []

    def handle(self, client, request):
        if request.id % 2:  # odd ids wait for an answer that never comes
            self.held.append((client, request.id))
        else:
            self.send(client, msg.Reply(request.id, b"x" * (request.id * 997)))

    def update_for(self, client, news):
        return None

    def forget(self, client):
        self.forgotten.append(client)


@pytest.fixture
def address():
    """A short directory of its own (a Unix socket's path has a length limit that pytest's
    per-test directories can pass)."""
    with tempfile.TemporaryDirectory() as directory:
        yield EngineAddress(0, "", f"ipc://{directory}/in", f"ipc://{directory}/out")


def _serve(address: EngineAddress) -> EngineTransport:
    transport = EngineTransport(Service, address, default_limits())
    transport.start()
    return transport


def test_answers_of_every_size_arrive_in_full_and_to_their_requests(address):
    engine = _serve(address)

    async def main():
        client = EngineClient(address.input, address.output)
        await client.start()
        ids = [2 * rng for rng in random.sample(range(1, 3000), 60)]  # up to 6 MB an answer
        answers = await asyncio.wait_for(asyncio.gather(*(client.call(msg.Status(i)) for i in ids)), 30)
        await client.stop()
        return ids, answers

    try:
        ids, answers = asyncio.run(main())
    finally:
        engine.stop()
    assert [len(a) for a in answers] == [i * 997 for i in ids]


def test_an_engine_that_goes_away_fails_what_it_held_and_is_found_again(address):
    engines = [_serve(address)]

    async def main():
        client = EngineClient(address.input, address.output)
        await client.start()
        held = asyncio.ensure_future(client.call(msg.Status(1)))  # never answered
        await asyncio.sleep(0.1)
        assert not held.done()
        gone_at = time.monotonic()
        await asyncio.to_thread(engines[0].stop)
        with pytest.raises(NotReady, match="went away"):
            await asyncio.wait_for(held, 5)
        failed_in = time.monotonic() - gone_at
        with pytest.raises(NotReady, match="not connected"):
            await client.call(msg.Status(2))
        client.tell(msg.Taken(0, 7))  # nobody waits for it: dropped, not raised
        engines.append(await asyncio.to_thread(_serve, address))
        for _ in range(100):
            try:
                answer = await client.call(msg.Status(4))
                break
            except NotReady:
                await asyncio.sleep(0.05)
        await client.stop()
        return failed_in, answer

    try:
        failed_in, answer = asyncio.run(main())
    finally:
        engines[-1].stop()
    assert failed_in < 2.0
    assert answer == b"x" * 4 * 997


def test_answers_for_an_api_process_that_went_away_are_dropped_after_the_grace(monkeypatch, address):
    monkeypatch.setattr(transport_module, "UNREACHABLE_GRACE_S", 0.2)
    engine = _serve(address)

    async def main():
        client = EngineClient(address.input, address.output)
        await client.start()
        asyncio.ensure_future(client.call(msg.Status(1)))
        for _ in range(100):
            if engine.service.held:
                break
            await asyncio.sleep(0.01)
        await client.stop()
        return client.identity

    try:
        identity = asyncio.run(main())
        assert engine.service.held == [(identity, 1)]
        engine.send(identity, msg.Reply(1, "late"))  # its API process is gone
        deadline = time.monotonic() + 5
        while not engine.service.forgotten and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        engine.stop()
    assert engine.service.forgotten == [identity]
    assert not any(t.is_alive() for t in threading.enumerate() if t.name.startswith("sdfserver-engine-"))


def test_answers_held_by_a_thread_leave_from_it_while_the_output_thread_idles_and_in_order(monkeypatch, address):
    """The held requests (odd ids) are answered by this thread inside ``holding()``: with the
    output thread idle they leave from this thread; the rest from the output thread; every
    answer reaches its request, the held ones in the order they were completed. A large held
    answer leaves from the output thread."""
    senders: list[str] = []
    encode = transport_module.framed

    def recorded(items, limit):
        senders.append(threading.current_thread().name)
        return encode(items, limit)

    monkeypatch.setattr(transport_module, "framed", recorded)
    engine = _serve(address)

    async def main():
        client = EngineClient(address.input, address.output)
        await client.start()
        got: list[int] = []
        calls = [asyncio.ensure_future(client.call(msg.Status(i))) for i in range(1, 41)]
        for call, i in zip(calls, range(1, 41)):
            call.add_done_callback(lambda _, i=i: got.append(i))
        for _ in range(200):
            if len(engine.service.held) == 20 and len(got) == 20:
                break
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.2)  # the output thread goes back to waiting
        sent_before = len(senders)
        for start in (0, 10):
            def answer(start=start):
                with engine.holding():
                    for client_id, request_id in engine.service.held[start:start + 10]:
                        engine.send(client_id, msg.Reply(request_id, request_id))
            await asyncio.to_thread(answer)
            await asyncio.sleep(0.2)
        answers = await asyncio.wait_for(asyncio.gather(*calls), 10)
        large = asyncio.ensure_future(client.call(msg.Status(41)))
        for _ in range(200):
            if len(engine.service.held) == 21:
                break
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.2)
        sent_small = len(senders)

        def answer_large():
            with engine.holding():
                client_id = engine.service.held[20][0]
                engine.send(client_id, msg.Reply(41, b"y" * (DIRECT_SEND_BYTES + 1)))

        await asyncio.to_thread(answer_large)
        large_answer = await asyncio.wait_for(large, 10)
        await client.stop()
        return answers, got, sent_before, sent_small, large_answer

    try:
        answers, got, sent_before, sent_small, large_answer = asyncio.run(main())
    finally:
        engine.stop()
    assert answers[1::2] == [b"x" * i * 997 for i in range(2, 41, 2)]
    assert answers[0::2] == list(range(1, 41, 2))
    assert got[20:] == list(range(1, 41, 2))
    assert set(senders[:sent_before]) == {"sdfserver-engine-output"}
    assert len(senders[sent_before:sent_small]) == 2  # each held block's answers in one frame, from its thread
    assert all(name.startswith("asyncio_") for name in senders[sent_before:sent_small]), senders
    # a large answer goes to the output thread: copying it would hold up the thread that completed it
    assert len(large_answer) == DIRECT_SEND_BYTES + 1
    assert senders[sent_small:] == ["sdfserver-engine-output"]
