"""The engine thread's life: warm-up, the loop that runs ``step()``, readiness, and failures.

- Warm-up builds the kernels before the engine answers anything. ``wait_started`` hands its
  failure to whoever starts the server, so that a server whose engine cannot start exits
  with the cause instead of listening.
- An exception a step raises fails that step's commands; the thread goes on (``core.py``).
- An OpenCL error means the device is lost. From then on the engine has a ``failure``: every
  command queued, waiting or submitted later fails at once with NotReady carrying it, and
  ``/readyz`` answers 503 with it.
- Should the thread die all the same (a bug outside a step), the same happens and
  ``on_death`` is called, so that the server process exits instead of staying up unable to serve.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from concurrent.futures import Future
from typing import Any, Callable

import numpy as np
import pyopencl as cl

from sdfserver.algorithms.exact import Exact
from sdfserver.edits import parse_edits
from sdfserver.engine.commands import StepReport
from sdfserver.engine.query import run_query
from sdfserver.errors import NotReady, SdfServerError
from sdfserver.geometry import Box
from sdfserver.gpu import GpuContext
from sdfserver.threadnames import name_os_thread
from sdfserver.world import MAX_SIDE_VOX, World, WorldConfig

log = logging.getLogger("sdfserver.engine")
Pending = tuple[Any, Future]


def warm_up(gpu: GpuContext) -> None:
    """Build the common kernels on a tiny world so the first request does not pay for it,
    and every variant of the exact transform's passes (the default algorithm), whatever
    region shapes edits bring."""
    started = time.perf_counter()
    variants = Exact().prebuild(gpu, MAX_SIDE_VOX)
    log.info("built %d exact kernel variants in %.1f s", variants, time.perf_counter() - started)
    world = World(gpu, WorldConfig(size=(16, 16, 16), chunk_size=8, max_distance=8))
    try:
        world.apply_edits(parse_edits([
            {"op": "voxels", "voxels": np.array([[1, 2, 3, 9]])},
            {"op": "box", "min": [4, 4, 4], "max": [6, 6, 6], "colour": 1},
            {"op": "sphere", "center": [10, 10, 10], "radius": 2, "colour": 2}]))
        world.recompute()
        world.read_field(Box((0, 0, 0), (8, 8, 8)))
        run_query(world, "points", np.array([[1.0, 2.0, 3.0]]))
        run_query(world, "spheres", np.array([[1.0, 2.0, 3.0, 1.0]]))
        run_query(world, "rays", np.array([[1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 8.0]]))
    finally:
        world.release()


def first_line(exc: BaseException) -> str:
    """``Type: the message's first line`` (a kernel build error carries its whole build log)."""
    lines = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__


class EngineLifetime:
    """The thread part of ``Engine``; the engine supplies ``step``, ``_drain`` and ``_release_all``."""

    gpu: GpuContext

    def __init__(self) -> None:
        self.failure: str | None = None  # why the engine cannot serve, for good
        self._commands: queue.SimpleQueue[Pending] = queue.SimpleQueue()
        self._waiting: list[Pending] = []
        self._wake = threading.Event()
        self._stopping = False
        self._thread: threading.Thread | None = None
        self._warm = threading.Event()
        self._on_death: Callable[[str], None] | None = None

    def step(self) -> StepReport:
        raise NotImplementedError

    def _drain(self) -> list[Pending]:
        raise NotImplementedError

    def _release_all(self) -> None:
        raise NotImplementedError

    def _held_all(self) -> list[Pending]:
        """Commands the engine holds back for later steps (none here; the engine's own)."""
        return []

    def start(self, warm_up: bool = True, on_death: Callable[[str], None] | None = None) -> None:
        """Start the engine thread; from then on only it touches the device. ``on_death(reason)``
        is called on that thread if it ever dies of an error."""
        self._on_death = on_death
        self._thread = threading.Thread(target=self._run, args=(warm_up,), name="sdfserver-engine", daemon=True)
        self._thread.start()

    def wait_started(self, timeout_s: float | None = None) -> str | None:
        """Wait for the warm-up; None once the engine serves, else why it cannot."""
        self._warm.wait(timeout_s)
        if not self._warm.is_set():
            return "the engine did not finish its warm-up in time"
        return self.failure

    def stop(self, timeout_s: float = 30.0) -> None:
        self._stopping = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        else:
            self._release_all()

    @property
    def started(self) -> bool:
        return self._thread is not None

    @property
    def ready(self) -> bool:
        alive = self._thread is not None and self._thread.is_alive() and not self._stopping
        return alive and self._warm.is_set() and self.failure is None

    def not_ready_reason(self) -> str:
        if self.failure is not None:
            return self.failure
        if self._thread is None or not self._thread.is_alive() or self._stopping:
            return "the engine is not running"
        return "the engine is warming up"

    def _refuse_if_failed(self, future: Future) -> bool:
        """Fail ``future`` at once when the engine cannot run it; True if it did."""
        if self.failure is None and not self._stopping:
            return False
        future.set_exception(NotReady(self.not_ready_reason()))
        return True

    def _run(self, warm_up: bool) -> None:
        name_os_thread()
        try:
            self._warm_up_once(warm_up)
            self._loop()
        except BaseException as exc:
            log.critical("the engine thread died", exc_info=exc)
            self.failure = f"the engine thread died: {first_line(exc)}"
            self._warm.set()
            self._fail_all(NotReady(self.failure), self._drain() + self._waiting + self._held_all())
            if self._on_death is not None:
                self._on_death(self.failure)
            return
        # reads still waiting for a version are cut off by the stop too: 503, as the queued ones
        self._fail_all(NotReady("the server is shutting down"), self._drain() + self._waiting + self._held_all())
        self._waiting = []
        self._release_all()

    def _warm_up_once(self, wanted: bool) -> None:
        try:
            if wanted:
                self._warm_up()
        except cl.Error as exc:
            self._lose_device(exc, [])
        except Exception as exc:  # a kernel that does not build, a bug: this engine cannot serve
            # a project error says all in its message; anything else is a bug, traceback and all
            log.error("the engine's warm-up failed: %s", exc, exc_info=not isinstance(exc, SdfServerError))
            self.failure = f"the engine could not start on {self.gpu.device_name}: {first_line(exc)}"
        self._warm.set()

    def _warm_up(self) -> None:
        warm_up(self.gpu)

    def _loop(self) -> None:
        while not self._stopping:
            self._wake.wait(self._wait_timeout())
            self._wake.clear()
            if self._stopping:
                break
            if self.failure is not None:  # submitted as the engine failed: answered, not run
                self._fail_all(NotReady(self.failure), self._drain())
                continue
            self.step()

    def _wait_timeout(self) -> float | None:
        if not self._waiting:
            return None
        return max(0.0, min(c.deadline for c, _ in self._waiting) - time.monotonic()) + 1e-3

    def _lose_device(self, exc: cl.Error, pending: list[Pending]) -> None:
        log.error("OpenCL device error; the engine stops serving: %s", exc)
        self.failure = f"device error: {exc}"
        self._fail_all(NotReady(self.failure), pending)

    def _fail_step(self, exc: Exception, pending: list[Pending]) -> None:
        """A step raised what no command handles: its commands fail (500 but for a project error
        with a status of its own), the engine goes on."""
        log.error("an engine step failed; its commands fail, the engine goes on", exc_info=exc)
        if not isinstance(exc, SdfServerError):  # logged here, once, not again for each command
            exc = SdfServerError(f"internal error in an engine step: {first_line(exc)}")
        self._fail_all(exc, pending)

    def _fail_all(self, exc: BaseException, pending: list[Pending]) -> None:
        for _, future in pending:
            if not future.done() and (future.running() or future.set_running_or_notify_cancel()):
                future.set_exception(exc)
