"""The engine process: one per device, owning its GpuContext, every World, the renderer and
the journal, speaking only typed messages (``messages.py``) over stream sockets.

Around the engine thread's ``step()`` loop run two threads that do all the socket work
(``transport.py``): the input thread reads every API process's requests and hands each to
``EngineService.handle``, which checks access and queues an engine command; the output thread
sends what the engine answered, one batch per API process.

``engine_main`` is the process's body: open the data directory, choose the device, restore
the stored worlds, warm up, then serve until SIGTERM. What it tells the launcher goes over a
pipe: ``("ready", device)``, ``("failed", why)`` or, should the engine thread die,
``("died", why)`` before it exits with status 1.
"""

from __future__ import annotations

import ctypes
import logging
import signal
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sdfserver.engine.access import Doorkeeper, RateLimiter
from sdfserver.engine.commands import EngineLimits
from sdfserver.engine.core import Engine
from sdfserver.engine.links import LinkLimits
from sdfserver.engine.metrics import EngineMetrics
from sdfserver.engine.service import EngineService
from sdfserver.engine.transport import EngineTransport
from sdfserver.errors import NoOpenCLDevice, SdfServerError
from sdfserver.settings import Settings

log = logging.getLogger("sdfserver.engine")
DEVICE_ADVICE = "`sdfserver devices` lists the usable OpenCL devices and --device picks one"


@dataclass(frozen=True)
class EngineAddress:
    """Where one engine listens (``ipc:///path`` or ``tcp://host:port``): API processes send
    requests to ``input`` and take answers from ``output``. ``credential``: the secret every
    connection to it proves it holds (``links.py``; required on TCP), None on Unix sockets,
    whose directory only the server's user can open."""

    index: int
    device: str  # the device spec this engine runs on ("" chooses)
    input: str
    output: str
    credential: bytes | None = field(default=None, repr=False)  # never printed


def engine_limits(settings: Settings) -> EngineLimits:
    return EngineLimits(edits=settings.edit_limits(), max_world_voxels=settings.max_world_voxels,
                        max_worlds=settings.max_worlds, max_read_voxels=settings.max_read_voxels,
                        max_subscription_voxels=settings.max_subscription_voxels,
                        max_subscriptions=settings.max_subscriptions,
                        max_subscriptions_per_key=settings.max_subscriptions_per_key,
                        max_wait_s=settings.max_wait_ms / 1e3,
                        max_recompute_voxel_visits=settings.max_recompute_voxel_visits or None,
                        busy_step_ms=settings.busy_step_ms, step_budget_ms=settings.step_budget_ms)


def data_dir_of(settings: Settings, index: int, engines: int) -> Path:
    """One engine keeps the data directory; several keep one sub-directory each."""
    return Path(settings.data_dir) if engines == 1 else Path(settings.data_dir) / f"engine-{index}"


def open_journal(settings: Settings, data_dir: Path):
    from sdfserver.storage import Storage
    from sdfserver.storage.journal import StorageJournal

    if not settings.persist:
        return None
    storage = Storage(data_dir, sync=settings.sync, commit_window_ms=settings.commit_window_ms,
                      sync_inline=settings.sync_inline)
    return StorageJournal(storage, snapshot_every_batches=settings.snapshot_every_batches,
                          snapshot_min_interval_s=settings.snapshot_min_interval_s)


def die_with_parent() -> None:
    """SIGKILL this process when the launcher dies, however it dies (Linux)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def engine_main(settings: Settings, address: EngineAddress, engines: int, conn: Any) -> int:
    """The engine process's body (after fork); its exit status."""
    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the launcher decides what Ctrl-C stops
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    return serve_engine(settings, address, engines, conn, stop)


def serve_engine(settings: Settings, address: EngineAddress, engines: int, conn: Any,
                 stop: threading.Event) -> int:
    """An engine on ``address`` until ``stop`` is set: restored, warmed up, its transport started;
    ``conn.send`` is told ("ready", device), ("failed", why) or ("died", why). The engine
    process's body, and a cluster's engine actor's (sdfserver/cluster)."""
    from sdfserver.engine.restore import restore_worlds
    from sdfserver.gcpauses import GcPauses, freeze_startup_objects
    from sdfserver.gpu import GpuContext
    from sdfserver.heap import keep_freed_memory
    from sdfserver.storage.lock import lock_data_dir

    # the engine process's threads share one GIL, and every socket read or write, log sync and
    # device wait lets go of it: the thread then waits up to this long to get it back
    sys.setswitchinterval(settings.switch_interval_ms / 1e3)
    journal = lock = engine = None
    try:
        try:
            journal = open_journal(settings, data_dir_of(settings, address.index, engines))
            lock = lock_data_dir(journal.storage.data_dir) if journal is not None else None
            gpu = GpuContext.create(address.device or None, settings.memory_budget_bytes)
            engine = Engine(gpu, engine_limits(settings), journal=journal, metrics=EngineMetrics())
        except SdfServerError as exc:  # no OpenCL device, unusable data directory
            advice = f" ({DEVICE_ADVICE})" if isinstance(exc, NoOpenCLDevice) else ""
            conn.send(("failed", f"{exc}{advice}"))
            return 1
        log.info("engine %d: device %s", address.index, gpu.device_name)
        if journal is not None:
            log.info("data directory: %s (sync %s)", journal.storage.data_dir, "on" if settings.sync else "OFF")
            restore_worlds(engine, journal.storage, journal)
        died: list[str] = []

        def on_death(reason: str) -> None:
            died.append(reason)
            stop.set()

        engine.start(warm_up=settings.warm_up, on_death=on_death)
        failure = engine.wait_started()
        if failure is not None:
            conn.send(("failed", f"{failure}; {DEVICE_ADVICE}"))
            return 1
        log.info("engine %d: %d start-up objects exempted from garbage collection", address.index,
                 freeze_startup_objects())
        keep_freed_memory()
        GcPauses(engine.metrics.registry, prefix="sdfserver_engine_gc")
        limiter = RateLimiter(settings.rate_limit_per_s, settings.rate_limit_burst)
        doorkeeper = Doorkeeper(limiter, engine.owner_of, lambda: list(engine.owners.values()))

        def writes_failure() -> str | None:
            failed = journal.storage.committer.failure if journal is not None else None
            return None if failed is None else str(failed)

        def peer_dir(index: int) -> Path:
            if not 0 <= index < engines:
                raise IndexError(f"there are {engines} engines")
            return data_dir_of(settings, index, engines)

        transport = EngineTransport(lambda send: EngineService(
            engine, doorkeeper, send, writes_failure=writes_failure, data_dir_of=peer_dir if engines > 1 else None,
            epoch=journal.storage.epoch if journal is not None else 0), address, LinkLimits.of(settings),
            registry=engine.metrics.registry)
        engine.answering = transport.holding
        if journal is not None:
            journal.storage.committer.completing = transport.holding
        transport.start()
        conn.send(("ready", gpu.device_name))
        while not stop.wait(0.5):
            pass
        transport.stop()
        if died:
            conn.send(("died", died[0]))
            return 1
        return 0
    finally:
        if engine is not None:
            engine.stop(timeout_s=5.0)
        if journal is not None:
            journal.close()
        if lock is not None:
            lock.close()
