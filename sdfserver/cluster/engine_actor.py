"""One engine as a Ray actor: the engine process's body (``engine/proc.serve_engine``) on a
thread of the actor's process, its sockets on TCP ports given by the launcher.

Ray re-runs the constructor when it restarts the actor (``max_restarts=-1``), with the same
arguments: the same ports and the same data directory, so the new incarnation restores every
world the old one acknowledged and listens where the API processes reconnect. Where
those ports are taken (another node, or another program since) it listens on free ones; the
cluster process sees the new address in ``describe`` and the API processes follow it.
"""

from __future__ import annotations

import os
import queue
import socket
import threading
from typing import Any

from sdfserver.engine.proc import EngineAddress, serve_engine
from sdfserver.settings import Settings

READY_TIMEOUT_S = 600.0  # restore and warm-up of every world this engine holds


def port_is_free(port: int) -> bool:
    """Whether the engine could listen on ``port`` (it binds with SO_REUSEADDR, so the old
    incarnation's connections lingering in TIME_WAIT do not count; another listener does)."""
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("", port))
        except OSError:
            return False
    return True


def free_ports(n: int) -> list[int]:
    sockets = [socket.socket() for _ in range(n)]
    try:
        for s in sockets:
            s.bind(("", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


class _Pipe:
    """What ``serve_engine`` tells its launcher, kept for the actor's methods."""

    def __init__(self) -> None:
        self.said: queue.Queue = queue.Queue()

    def send(self, item: tuple[str, str]) -> None:
        self.said.put(item)


class EngineActor:
    def __init__(self, settings_json: str, index: int, engines: int, host: str, ports: tuple[int, int]):
        settings = Settings.model_validate_json(settings_json)
        self.index = index
        if not host:
            import ray

            host = ray.util.get_node_ip_address()
        if not all(port_is_free(p) for p in ports):
            ports = tuple(free_ports(2))
        bind = EngineAddress(index, settings.device, f"tcp://0.0.0.0:{ports[0]}", f"tcp://0.0.0.0:{ports[1]}")
        self.address = EngineAddress(index, settings.device, f"tcp://{host}:{ports[0]}", f"tcp://{host}:{ports[1]}")
        self._stop = threading.Event()
        self._pipe = _Pipe()
        self._thread = threading.Thread(target=serve_engine, args=(settings, bind, engines, self._pipe, self._stop),
                                        name="sdfserver-engine-main", daemon=True)
        self._thread.start()
        kind, text = self._pipe.said.get(timeout=READY_TIMEOUT_S)
        if kind != "ready":
            raise RuntimeError(f"engine {index} could not start: {text}")
        self.device = text

    def describe(self) -> dict[str, Any]:
        """Where this incarnation listens and runs."""
        return {"index": self.index, "input": self.address.input, "output": self.address.output,
                "device": self.device, "pid": os.getpid(), "node": socket.gethostname()}

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=30)
