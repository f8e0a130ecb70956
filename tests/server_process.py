"""A real ``sdfserver serve`` process for tests: on a free loopback port, with its data directory,
its output in a log file beside that directory, waited for until ``/readyz`` answers, stopped or
killed. Every test directory that needs a server starts it through here."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
READY_TIMEOUT_S = 120.0  # PoCL builds the kernels while the server warms up


def tree_rss_bytes(pid: int) -> int:
    """Resident memory of a server: the launcher, its engine processes and its API processes."""
    total, pids = 0, [pid]
    while pids:
        pid = pids.pop()
        try:
            for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1]) * 1024
            for task in Path(f"/proc/{pid}/task").iterdir():
                pids += [int(c) for c in (task / "children").read_text().split()]
        except FileNotFoundError:  # gone meanwhile (an API process being replaced)
            continue
    return total


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def checkout_env(*paths: Path) -> dict[str, str]:
    """This environment with the checkout (and ``paths``) on PYTHONPATH and no SDFSERVER_*
    settings: a developer's own keys, port or data directory must not leak into what tests start."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("SDFSERVER_")}
    entries = [str(ROOT), *(str(p) for p in paths)]
    if env.get("PYTHONPATH"):
        entries.append(env["PYTHONPATH"])
    env["PYTHONPATH"] = os.pathsep.join(entries)
    return env


class ServerProcess:
    def __init__(self, data_dir: Path, *flags: str, env: dict | None = None, port: int | None = None):
        """``port``: a given one (a test of a port in use) instead of a free one."""
        self.port = free_port() if port is None else port
        self.url = f"http://127.0.0.1:{self.port}"
        self.log_path = Path(data_dir).parent / f"server-{self.port}.log"
        self.log = open(self.log_path, "wb")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "sdfserver", "serve", "--host", "127.0.0.1", "--port", str(self.port),
             "--data-dir", str(data_dir), *flags],
            cwd=ROOT, env={**checkout_env(), **(env or {})}, stdout=self.log, stderr=subprocess.STDOUT)

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> "ServerProcess":
        deadline = time.monotonic() + timeout_s
        while True:
            if self.process.poll() is not None:
                output = self.output()
                self.close()
                raise RuntimeError(f"server exited {self.process.returncode}: {output}")
            try:
                if httpx.get(self.url + "/readyz", timeout=2).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                self.kill()
                raise RuntimeError(f"server did not become ready in {timeout_s:g} s: {self.output()}")
            time.sleep(0.05)

    def output(self) -> str:
        """The end of what the server printed."""
        if not self.log.closed:
            self.log.flush()
        return self.log_path.read_text(errors="replace")[-4000:]

    def kill(self) -> None:
        """SIGKILL: a crash, as far as the data directory can tell."""
        if self.process.poll() is None:
            os.kill(self.process.pid, signal.SIGKILL)
        self.process.wait()
        self.close()

    def stop(self, timeout_s: float = 15) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.close()

    def close(self) -> None:
        self.log.close()


def server_starter(factory, tmp_path: Path):
    """The body of a ``start_server`` fixture: yields ``start(*flags, data_dir=None, ready=True,
    **kw)``, which makes a server with ``factory`` over the test's own data directory (waited
    for until ready unless ``ready=False``); every server it started is stopped afterwards."""
    started: list[ServerProcess] = []

    def start(*flags: str, data_dir: Path | None = None, ready: bool = True, **kw) -> ServerProcess:
        server = factory(data_dir or tmp_path / "data", *flags, **kw)
        started.append(server)
        return server.wait_ready() if ready else server

    yield start
    for server in started:
        if server.process.poll() is None:
            server.stop()
        elif not server.log.closed:
            server.close()
