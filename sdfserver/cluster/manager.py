"""The launcher's cluster process: Ray's driver, so that the launcher and the API processes it
forks never hold Ray's threads.

It joins the cluster (``settings.cluster``: ``local`` starts one on this machine), creates the
engine actors — named ``sdfserver-engine-<i>`` in the ``sdfserver`` namespace, detached,
restarted without limit, each asking for ``engine_gpus`` GPUs — waits until each has restored
its worlds and listens, and tells the launcher their addresses. Then it watches them: a restart
(a new process behind the same name) is logged with the time it took to serve again, and an
engine restarted where it listens at another address (another node, or its ports taken) has its
addresses rewritten in the launcher's addresses file, which the API processes follow.
"""

from __future__ import annotations

import json
import logging
import signal
import threading
import time
from typing import Any

from sdfserver.engine.proc import EngineAddress, die_with_parent
from sdfserver.settings import Settings
from sdfserver.storage.fsutil import write_atomic

log = logging.getLogger("sdfserver.cluster")
NAMESPACE = "sdfserver"
WATCH_EVERY_S = 1.0
DESCRIBE_TIMEOUT_S = 600.0  # an engine restores every world it holds before it answers


def engine_name(index: int) -> str:
    return f"sdfserver-engine-{index}"


def missing_gpus(ray: Any, settings: Settings) -> str | None:
    """Why the engines cannot all be placed now, or None: Ray would otherwise wait for GPUs that
    never come, and the server would never listen."""
    needed = settings.engines * settings.engine_gpus
    has = ray.cluster_resources().get("GPU", 0.0)
    if needed > has + 1e-9:
        return (f"{settings.engines} engines x {settings.engine_gpus:g} GPUs need {needed:g} GPUs; the Ray cluster "
                f"has {has:g} (--engine-gpus 0 runs the engines on CPU devices)")
    return None


def start_engines(ray: Any, settings: Settings) -> list[Any]:
    """The engine actors, created or (detached ones left by an earlier launcher) found again."""
    from sdfserver.cluster.engine_actor import EngineActor, free_ports

    remote = ray.remote(EngineActor)
    host = "127.0.0.1" if settings.cluster == "local" else ""  # "": the node the actor runs on
    ports = free_ports(2 * settings.engines)
    return [remote.options(name=engine_name(i), namespace=NAMESPACE, lifetime="detached", get_if_exists=True,
                           max_restarts=-1, max_task_retries=-1, num_gpus=settings.engine_gpus, num_cpus=0)
            .remote(settings.model_dump_json(), i, settings.engines, host, (ports[2 * i], ports[2 * i + 1]))
            for i in range(settings.engines)]


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
        ray.init(address=None if local else settings.cluster, namespace=NAMESPACE, include_dashboard=False,
                 log_to_driver=True, configure_logging=False)
        short = missing_gpus(ray, settings)
        if short is not None:
            conn.send(("failed", short))
            _leave(ray, local)
            return 1
        actors = start_engines(ray, settings)
        described = ray.get([a.describe.remote() for a in actors], timeout=DESCRIBE_TIMEOUT_S)
    except Exception as exc:  # Ray's own errors: no cluster, an engine that cannot start
        conn.send(("failed", f"the cluster could not start its engines: {type(exc).__name__}: {exc}"))
        _leave(ray, local)
        return 1
    for d in described:
        log.info("engine %d: %s on %s (pid %d), %s", d["index"], d["device"], d["node"], d["pid"], d["input"])
    publish(addresses_file, described)
    conn.send(("ready", [EngineAddress(d["index"], d["device"], d["input"], d["output"]) for d in described]))
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
