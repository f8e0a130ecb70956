"""Who reads the engine's request sockets (``intake.py``): the engine thread itself while it waits
for work, the input thread while it steps; every request read once, in the order it came."""

from __future__ import annotations

import socket
import tempfile
import threading
import time

from sdfserver.engine import frames
from sdfserver.engine import messages as msg
from sdfserver.engine.intake import Intake
from sdfserver.engine.lifetime import WakeFlag


def test_an_idle_engine_reads_requests_itself_and_a_stepping_one_leaves_them_to_the_input_thread():
    handled: list[tuple[int, str]] = []
    wake = WakeFlag()

    def handle(identity: bytes, request) -> None:
        assert identity == b"api-1"
        handled.append((request.id, threading.current_thread().name))
        wake.set()  # as the engine's submit does

    with tempfile.TemporaryDirectory() as directory:
        listener = frames.listen(f"ipc://{directory}/in")
        intake = Intake(listener, handle)
        engine_wait = intake.lend_to(wake)
        stop = threading.Event()
        steps = []

        def engine() -> None:
            while not stop.is_set():
                engine_wait(0.2)
                wake.clear()
                steps.append(len(handled))
                time.sleep(0.004 if len(handled) > 20 else 0)  # later steps take a while

        threads = [threading.Thread(target=intake.run_input, name="input"), threading.Thread(target=engine, name="engine")]
        for thread in threads:
            thread.start()
        client = socket.socket(socket.AF_UNIX)
        client.connect(f"{directory}/in")
        client.sendall(frames.frame(b"api-1"))
        for request_id in range(1, 21):  # one at a time, the engine idle in between
            client.sendall(frames.frame(msg.REQUEST_ENCODER.encode(msg.Status(request_id))))
            time.sleep(0.01)
        for request_id in range(21, 221):  # a stream while the engine steps
            client.sendall(frames.frame(msg.REQUEST_ENCODER.encode(msg.Status(request_id))))
            time.sleep(0.0002)
        deadline = time.monotonic() + 10
        while len(handled) < 220 and time.monotonic() < deadline:
            time.sleep(0.01)
        stop.set()
        intake.stop()
        for thread in threads:
            thread.join(5)
        client.close()

    assert [request_id for request_id, _ in handled] == list(range(1, 221))
    lone = [name for request_id, name in handled if request_id <= 20]
    assert lone.count("engine") >= 18, lone  # the first may come before the engine asked
    assert {name for request_id, name in handled if request_id > 20} == {"engine", "input"}
    assert not any(thread.is_alive() for thread in threads)


def test_a_long_step_that_kept_the_sockets_leaves_the_next_requests_to_the_input_thread():
    handled: list[tuple[int, str, float]] = []
    wake = WakeFlag()

    def handle(identity: bytes, request) -> None:
        handled.append((request.id, threading.current_thread().name, time.monotonic()))
        wake.set()

    with tempfile.TemporaryDirectory() as directory:
        intake = Intake(frames.listen(f"ipc://{directory}/in"), handle)
        engine_wait = intake.lend_to(wake)
        stop = threading.Event()
        step_ends: list[float] = []

        def engine() -> None:
            while not stop.is_set():
                engine_wait(0.2)
                wake.clear()
                if handled and handled[-1][0] == 1 and not step_ends:
                    time.sleep(0.3)  # the step request 1 started, long
                    step_ends.append(time.monotonic())

        threads = [threading.Thread(target=intake.run_input, name="input"), threading.Thread(target=engine, name="engine")]
        for thread in threads:
            thread.start()
        client = socket.socket(socket.AF_UNIX)
        client.connect(f"{directory}/in")
        client.sendall(frames.frame(b"api-1"))
        time.sleep(0.05)  # the engine idle: it reads, and keeps the sockets through request 1's step
        client.sendall(frames.frame(msg.REQUEST_ENCODER.encode(msg.Status(1))))
        time.sleep(0.05)
        client.sendall(frames.frame(msg.REQUEST_ENCODER.encode(msg.Status(2))))
        deadline = time.monotonic() + 5
        while (len(handled) < 2 or not step_ends) and time.monotonic() < deadline:
            time.sleep(0.01)
        stop.set()
        intake.stop()
        for thread in threads:
            thread.join(5)
        client.close()

    (first, first_by, _), (second, second_by, second_at) = handled
    assert (first, first_by, second, second_by) == (1, "engine", 2, "input")
    assert second_at < step_ends[0] - 0.2  # taken in within the step, not after it
