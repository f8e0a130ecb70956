"""The launcher's cluster process: Ray's driver, so that the launcher and the API processes it
forks never hold Ray's threads.

It joins the cluster (``settings.cluster``: ``local`` starts one on this machine), creates the
engine actors — named ``sdfserver-engine-<i>`` in the ``sdfserver`` namespace, detached,
restarted without limit, each asking for ``engine_gpus`` GPUs (unset: one if the cluster has
GPUs, none if it has none) — waits until each has restored its worlds and listens, and tells
the launcher their addresses and credentials (``engine/links.py``: made here, one per engine
created, asked of an engine found again). Then it watches them: a restart (a new process behind
the same name) is logged with the time it took to serve again, and an engine restarted where it
listens at another address (another node, or its ports taken) has its addresses rewritten in the
launcher's addresses file, which the API processes follow.

Ray's own signal handlers, which ``ray.init`` installs, print a stack dump for the SIGTERM that
stops a server and exit as if it crashed; this process sets its own again after ``ray.init``,
so that a stop leaves the cluster cleanly and quietly. An engine actor that dies is said once,
plainly, by ``watch``; Ray's paragraph about it (OOM killers, ``ray stop``, resource isolation)
is kept out of the log (``quiet_worker_deaths``), and what the actors themselves print still
reaches it.
"""

from __future__ import annotations

import json
import logging
import signal
import threading
import time
from typing import Any

from sdfserver.engine.links import new_credential
from sdfserver.engine.proc import EngineAddress, die_with_parent
from sdfserver.settings import Settings
from sdfserver.storage.fsutil import write_atomic

log = logging.getLogger("sdfserver.cluster")
NAMESPACE = "sdfserver"
WATCH_EVERY_S = 1.0
RAY_WORKER_DEATH = "A worker died or was killed"  # how the raylet's notice of a dead actor begins
DESCRIBE_TIMEOUT_S = 600.0  # an engine restores every world it holds before it answers


def engine_name(index: int) -> str:
    return f"sdfserver-engine-{index}"


def gpus_per_engine(settings: Settings, has: float) -> tuple[float, str | None]:
    """(the GPUs each engine asks Ray for, why the engines cannot all be placed or None) on a
    cluster with ``has`` GPUs. Ray would otherwise wait for GPUs that never come, and the server
    would never listen."""
    gpus = settings.engine_gpus
    if gpus is None:
        gpus = 1.0 if has > 0 else 0.0
    needed = settings.engines * gpus
    if needed > has + 1e-9:
        return gpus, (f"{settings.engines} engines x {gpus:g} GPUs need {needed:g} GPUs; the Ray cluster has "
                      f"{has:g} (--engine-gpus 0 runs the engines on CPU devices, a fraction shares a GPU)")
    return gpus, None


def start_engines(ray: Any, settings: Settings, gpus: float) -> list[Any]:
    """The engine actors, created or (detached ones left by an earlier launcher) found again."""
    from sdfserver.cluster.engine_actor import EngineActor, free_ports

    remote = ray.remote(EngineActor)
    host = "127.0.0.1" if settings.cluster == "local" else ""  # "": the node the actor runs on
    ports = free_ports(2 * settings.engines)
    return [remote.options(name=engine_name(i), namespace=NAMESPACE, lifetime="detached", get_if_exists=True,
                           max_restarts=-1, max_task_retries=-1, num_gpus=gpus, num_cpus=0)
            .remote(settings.model_dump_json(), i, settings.engines, host, (ports[2 * i], ports[2 * i + 1]),
                    new_credential())
            for i in range(settings.engines)]


def wait_started(ray: Any, actors: list[Any], stop: threading.Event) -> tuple[list[dict], list[bytes]] | None:
    """Each engine described once it has restored its worlds and listens, and its credential;
    None when the server is stopped first."""
    asked = [a.describe.remote() for a in actors] + [a.credential.remote() for a in actors]
    deadline = time.monotonic() + DESCRIBE_TIMEOUT_S
    while True:
        _, waiting = ray.wait(asked, num_returns=len(asked), timeout=WATCH_EVERY_S)
        if not waiting:
            answers = ray.get(asked)
            return answers[:len(actors)], answers[len(actors):]
        if stop.is_set():
            return None
        if time.monotonic() > deadline:
            raise TimeoutError(f"{len(waiting)} engine answers did not come in {DESCRIBE_TIMEOUT_S:g} s")


def quiet_worker_deaths() -> None:
    """Ray prints each notice its raylets publish to the driver through one function of its
    private worker module (it has no public hook for this); that function is wrapped to drop the
    notices of dead workers, which stay in Ray's own logs (``raylet.out``). A Ray without it is
    said so once, and its notices stay in this log."""
    import ray._private.worker as ray_worker

    printer = getattr(ray_worker, "print_to_stdstream", None)
    if printer is None:
        log.info("Ray's notices of dead engine actors stay in the log: this Ray has no print_to_stdstream to wrap")
        return

    def without_deaths(data: dict, ignore_prefix: bool) -> None:
        if data.get("pid") == "raylet":
            lines = [line for line in data.get("lines", []) if not line.startswith(RAY_WORKER_DEATH)]
            if not lines:
                return
            data = {**data, "lines": lines}
        printer(data, ignore_prefix)

    ray_worker.print_to_stdstream = without_deaths


def publish(path: str | None, described: list[dict]) -> None:
    """Write the engines' addresses where the API processes look (atomically: whole or not at all)."""
    if path is None:
        return
    entries = [{"index": d["index"], "input": d["input"], "output": d["output"]} for d in described]
    write_atomic(path, json.dumps(entries).encode())


def cluster_main(settings: Settings, conn: Any, addresses_file: str | None = None) -> int:
    """The cluster process's body (after fork); its exit status."""
    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        import ray
    except ImportError:
        conn.send(("failed", "--cluster needs Ray: pip install 'sdfserver[ray]'"))
        return 1
    local = settings.cluster == "local"
    try:
        # "local": always a cluster of this server's own, never another found on this machine
        ray.init(address=settings.cluster, namespace=NAMESPACE, include_dashboard=False, log_to_driver=True,
                 configure_logging=False)
        signal.signal(signal.SIGTERM, lambda *_: stop.set())  # again: ray.init installed its own
        quiet_worker_deaths()
        has = ray.cluster_resources().get("GPU", 0.0)
        gpus, short = gpus_per_engine(settings, has)
        if short is not None:
            conn.send(("failed", short))
            _leave(ray, local)
            return 1
        if settings.engine_gpus is None:
            log.info("the Ray cluster has %g GPUs: each engine asks for %g%s (--engine-gpus sets it)", has, gpus,
                     ", so the engines run on CPU devices" if not gpus else "")
        actors = start_engines(ray, settings, gpus)
        started = wait_started(ray, actors, stop)
    except Exception as exc:  # Ray's own errors: no cluster, an engine that cannot start
        conn.send(("failed", f"the cluster could not start its engines: {type(exc).__name__}: {exc}"))
        _leave(ray, local)
        return 1
    if started is None:  # stopped while the engines were starting
        _leave(ray, local)
        return 0
    described, credentials = started
    for d in described:
        log.info("engine %d: %s on %s (pid %d), %s", d["index"], d["device"], d["node"], d["pid"], d["input"])
    publish(addresses_file, described)
    conn.send(("ready", [EngineAddress(d["index"], d["device"], d["input"], d["output"], credential)
                         for d, credential in zip(described, credentials)]))
    try:
        watch(ray, actors, described, stop, addresses_file)
    finally:
        _leave(ray, local)
    return 0


def watch(ray: Any, actors: list[Any], described: list[dict], stop: threading.Event,
          addresses_file: str | None = None) -> None:
    pids = [d["pid"] for d in described]
    while not stop.wait(WATCH_EVERY_S):
        for i, actor in enumerate(actors):
            asked = time.monotonic()
            try:
                now = ray.get(actor.describe.remote(), timeout=DESCRIBE_TIMEOUT_S)
            except Exception as exc:
                log.warning("engine %d does not answer: %s", i, exc)
                continue
            if now["pid"] != pids[i]:
                log.warning("engine %d was restarted (pid %d, then %d); serving again %.1f s after it was missed",
                            i, pids[i], now["pid"], time.monotonic() - asked)
                pids[i] = now["pid"]
                if (now["input"], now["output"]) != (described[i]["input"], described[i]["output"]):
                    log.warning("engine %d now listens at %s on %s", i, now["input"], now["node"])
                    described[i] = now
                    publish(addresses_file, described)


def _leave(ray: Any, local: bool) -> None:
    """A local cluster goes with this driver, engines included; the detached engines of a joined
    cluster stay, for the next ``serve`` to find by name."""
    ray.shutdown()
