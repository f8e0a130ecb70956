"""One engine as a Ray actor: the engine process's body (``engine/proc.serve_engine``) on a
thread of the actor's process, its sockets on TCP ports given by the launcher.

It listens on the address it advertises (``engine_bind_host`` may widen that), and every
connection must prove it holds the credential the cluster process made with the actor
(``engine/links.py``): the port is reachable from the node's network, the secret is not.

Ray re-runs the constructor when it restarts the actor (``max_restarts=-1``), with the same
arguments: the same ports, the same credential and the same data directory, so the new
incarnation restores every world the old one acknowledged and listens where the API processes
reconnect, believing the same proofs. Where those ports are taken (another node, or another
program since) it listens on free ones; the cluster process sees the new address in
``describe`` and the API processes follow it.
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


def port_is_free(port: int, host: str = "") -> bool:
    """Whether the engine could listen on ``port`` of ``host`` (it binds with SO_REUSEADDR, so
    the old incarnation's connections lingering in TIME_WAIT do not count; another listener does)."""
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError:
            return False
    return True


def free_ports(n: int, host: str = "") -> list[int]:
    sockets = [socket.socket() for _ in range(n)]
    try:
        for s in sockets:
            s.bind((host, 0))
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
    def __init__(self, settings_json: str, index: int, engines: int, host: str, ports: tuple[int, int],
                 credential: bytes):
        settings = Settings.model_validate_json(settings_json)
        self.index = index
        if not host:
            import ray

            host = ray.util.get_node_ip_address()
        bind_host = settings.engine_bind_host or host
        if not all(port_is_free(p, bind_host) for p in ports):
            ports = tuple(free_ports(2, bind_host))
        bind = EngineAddress(index, settings.device, f"tcp://{bind_host}:{ports[0]}", f"tcp://{bind_host}:{ports[1]}",
                             credential)
        self.address = EngineAddress(index, settings.device, f"tcp://{host}:{ports[0]}", f"tcp://{host}:{ports[1]}",
                                     credential)
        self._stop = threading.Event()
        self._pipe = _Pipe()
        self._thread = threading.Thread(target=serve_engine, args=(settings, bind, engines, self._pipe, self._stop),
                                        name="sdfserver-engine-main", daemon=True)
        self._thread.start()
        kind, text = self._pipe.said.get(timeout=READY_TIMEOUT_S)
        if kind != "ready":
            raise RuntimeError(f"engine {index} could not start: {text}")
        self.device = text

    def credential(self) -> bytes:
        """What a connection to this engine proves it holds: asked by the cluster process, which
        may have found this (detached) engine where an earlier one left it."""
        return self.address.credential

    def describe(self) -> dict[str, Any]:
        """Where this incarnation listens and runs (never the credential: this is logged)."""
        return {"index": self.index, "input": self.address.input, "output": self.address.output,
                "device": self.device, "pid": os.getpid(), "node": socket.gethostname()}

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=30)
