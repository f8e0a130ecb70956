"""``sdfserver serve``: the launcher of one engine process per device and N identical API
processes sharing one listening socket.

Flags are generated from the Settings fields (``--max-request-bytes`` for
``max_request_bytes``) and override ``SDFSERVER_*`` environment variables.

Start-up in order: the listening socket (``port.py``: a second server stops here), one engine
process per device in ``--devices`` (each opens its data directory, its device and its stored
worlds, and warms up), then ``--workers`` API processes on that socket. What fails on the way
is said in one line, with exit status 1; Ctrl-C during the warm-up exits 130.

While serving, the launcher watches its children: an API process that dies is started again;
an engine process that dies ends the server (every API process is stopped, exit status 1, the
engine's cause in one line), so that a supervisor starts it again rather than a server
answering without its engine. SIGTERM stops the API processes first, then the engines.
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing
import os
import shutil
import signal
import sys
import tempfile
import time
import typing
from multiprocessing.connection import wait
from typing import Any

from pydantic import ValidationError

from sdfserver.errors import SdfServerError
from sdfserver.settings import Settings, log_unknown_environment, worker_count

log = logging.getLogger("sdfserver")
RESTART_QUIET_S = 1.0  # an API process that lived less than this is started again after this long


def _flag_type(annotation: Any) -> tuple[Any, list[str] | None]:
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if typing.get_origin(annotation) is typing.Literal:
        return str, [str(a) for a in typing.get_args(annotation)]
    if args and annotation not in (int, float, str, bool):
        return _flag_type(args[0])
    return annotation, None


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sdfserver serve",
                                description="Run the sdfserver HTTP/WebSocket server. Every flag also reads "
                                            "from SDFSERVER_<NAME>; see docs/configuration.md.")
    for name, info in Settings.model_fields.items():
        flag = "--" + name.replace("_", "-")
        kind, choices = _flag_type(info.annotation)
        help_text = f"{info.description} (default: {info.default!r})".replace("%", "%%")
        if kind is bool:
            p.add_argument(flag, dest=name, action=argparse.BooleanOptionalAction, default=None, help=help_text)
        else:
            p.add_argument(flag, dest=name, type=kind, choices=choices, default=None, help=help_text)
    return p


def settings_from(argv: list[str]) -> Settings:
    """Environment first, then flags on top."""
    overrides = {k: v for k, v in vars(parser().parse_args(argv)).items() if v is not None}
    return Settings(**overrides)


class Stop(Exception):
    """SIGTERM: stop serving."""


def _raise_stop(*_: Any) -> None:
    raise Stop()


def main(argv: list[str] | None = None) -> int:
    from sdfserver.api.auth import is_loopback, parse_keys
    from sdfserver.api.logs import configure_logging
    from sdfserver.api.port import cannot_listen, listen_once

    try:
        settings = settings_from(list(sys.argv[1:] if argv is None else argv))
    except ValidationError as exc:
        print(f"sdfserver serve: invalid settings:\n{exc}", file=sys.stderr)
        return 2
    log_config = configure_logging(settings)
    log_unknown_environment()
    try:
        keys = parse_keys(settings.api_keys, settings.api_key_file)
    except SdfServerError as exc:
        print(f"sdfserver serve: {exc}", file=sys.stderr)
        return 2
    if not keys and not is_loopback(settings.host):
        print(f"sdfserver serve: refusing to listen on {settings.host} with no API keys configured; set "
              "SDFSERVER_API_KEYS / --api-keys or --api-key-file, or listen on 127.0.0.1", file=sys.stderr)
        return 2
    try:  # before any warm-up: a second server on this port stops at once
        sock = listen_once(settings.host, settings.port)
    except OSError as exc:
        print(f"sdfserver serve: {cannot_listen(settings.host, settings.port, exc)}", file=sys.stderr)
        return 1
    run_dir = tempfile.mkdtemp(prefix="sdfserver-")
    launcher = Launcher(settings, sock, run_dir, log_config)
    signal.signal(signal.SIGTERM, _raise_stop)
    try:
        return launcher.run()
    except (KeyboardInterrupt, Stop) as exc:
        launcher.stop()
        return 130 if isinstance(exc, KeyboardInterrupt) and not launcher.serving else 0
    finally:
        launcher.stop()
        sock.close()
        shutil.rmtree(run_dir, ignore_errors=True)


class Launcher:
    def __init__(self, settings: Settings, sock: Any, run_dir: str, log_config: Any):
        from sdfserver.engine.proc import EngineAddress

        self.settings = settings
        self.sock = sock
        self.log_config = log_config
        self.context = multiprocessing.get_context("fork")  # children inherit the socket and the imports
        specs = [d.strip() for d in settings.devices.split(",")] if settings.devices.strip() else [settings.device]
        self.addresses = [EngineAddress(i, spec, f"ipc://{run_dir}/engine-{i}-in", f"ipc://{run_dir}/engine-{i}-out")
                          for i, spec in enumerate(specs)]
        # where the cluster process tells the API processes an engine's new address (an actor
        # restarted on another node); None without a cluster
        self.addresses_file = os.path.join(run_dir, "engines.json") if settings.cluster else None
        self.engines: list[tuple[Any, Any]] = []  # (process, pipe)
        self.workers: list[tuple[Any, float]] = []  # (process, started at)
        self.serving = False
        self._stopped = False

    def run(self) -> int:
        failure = self._start_cluster() if self.settings.cluster else self._start_engines()
        if failure is not None:
            print(f"sdfserver serve: {failure}", file=sys.stderr)
            return 1
        import sdfserver.api.worker  # noqa: F401  imported once here, inherited by every API process
        from sdfserver.api.connections import say_descriptor_room
        from sdfserver.api.counts import SharedCounts

        workers = worker_count(self.settings)
        self.counts = SharedCounts(workers)  # before the fork: every API process shares it
        self.workers = [self._start_worker(row) for row in range(workers)]
        self.serving = True
        host, port = self.sock.getsockname()[:2]
        log.info("listening on http://%s:%d (%d API processes, %d engines%s)", host, port, len(self.workers),
                 len(self.addresses), f", Ray cluster {self.settings.cluster}" if self.settings.cluster else "")
        say_descriptor_room(self.settings, workers)
        return self._watch()

    def _start_cluster(self) -> str | None:
        """The cluster process (sdfserver/cluster/manager.py), watched as an engine process is:
        it tells the engine actors' addresses once every one serves."""
        from sdfserver.cluster.manager import cluster_main

        receiver, sender = self.context.Pipe(duplex=False)
        process = self.context.Process(target=_exit_with, args=(cluster_main, self.settings, sender,
                                                                  self.addresses_file),
                                       name="sdfserver-cluster")
        process.start()
        sender.close()
        self.engines.append((process, receiver))
        ready, said = self._wait_ready(process, receiver)
        if ready:
            self.addresses = said
        return None if ready else said

    def _start_engines(self) -> str | None:
        from sdfserver.engine.proc import engine_main

        for address in self.addresses:
            receiver, sender = self.context.Pipe(duplex=False)
            process = self.context.Process(target=_exit_with, args=(engine_main, self.settings, address,
                                                                      len(self.addresses), sender),
                                           name=f"sdfserver-engine-{address.index}")
            process.start()
            sender.close()
            self.engines.append((process, receiver))
        for process, pipe in self.engines:  # listen only once every engine has shown it can serve
            ready, said = self._wait_ready(process, pipe)
            if not ready:
                return said
        return None

    def _wait_ready(self, process: Any, pipe: Any) -> tuple[bool, Any]:
        """(True, what the child said with "ready") or (False, why it cannot serve)."""
        while True:
            if pipe.poll(0.1):
                try:
                    kind, said = pipe.recv()
                except EOFError:
                    return False, f"the {_role(process)} process exited with status {process.exitcode}"
                return kind == "ready", said
            if not process.is_alive() and not pipe.poll(0):
                return False, f"the {_role(process)} process exited with status {process.exitcode}"

    def _start_worker(self, row: int) -> tuple[Any, float]:
        """The API process that counts in ``row`` of the shared counts (a replacement takes its row)."""
        from sdfserver.api.worker import worker_main

        process = self.context.Process(target=_exit_with, args=(worker_main, self.settings, self.sock,
                                                                 self.addresses, self.log_config,
                                                                 self.addresses_file, self.counts.for_process(row)),
                                       name="sdfserver-api")
        process.start()
        return process, time.monotonic()

    def _watch(self) -> int:
        while True:
            sentinels = [p.sentinel for p, _ in self.engines] + [p.sentinel for p, _ in self.workers]
            wait(sentinels, timeout=1.0)
            for process, pipe in self.engines:
                if not process.is_alive():
                    reason = _death_of(process, pipe)
                    self.stop()  # first: what the API processes log as they stop comes before the cause
                    print(f"sdfserver serve: {reason}; exiting, so that a supervisor can start it again",
                          file=sys.stderr)
                    return 1
            for i, (process, started) in enumerate(self.workers):
                if not process.is_alive():
                    log.warning("API process %d exited with status %s; starting another", process.pid,
                                process.exitcode)
                    if time.monotonic() - started < RESTART_QUIET_S:
                        time.sleep(RESTART_QUIET_S)  # no crash loop
                    self.workers[i] = self._start_worker(i)

    def stop(self) -> None:
        if self._stopped:
            return
        self._stopped = True
        for group, grace in ((self.workers, 10.0), (self.engines, 30.0)):
            for process, _ in group:
                if process.is_alive():
                    process.terminate()
            deadline = time.monotonic() + grace
            for process, _ in group:
                process.join(max(0.0, deadline - time.monotonic()))
                if process.is_alive():
                    process.kill()
                    process.join()


def _death_of(process: Any, pipe: Any) -> str:
    try:
        while pipe.poll(0):
            kind, text = pipe.recv()
            if kind == "died":
                return text
    except (EOFError, OSError):
        pass
    return f"the {_role(process)} process exited with status {process.exitcode}"


def _role(process: Any) -> str:
    """"engine" or "cluster", from the child's name (sdfserver-engine-<i>, sdfserver-cluster)."""
    return process.name.removeprefix("sdfserver-").split("-")[0]


def _exit_with(main: Any, *args: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # the child's own handlers, not the launcher's
    raise SystemExit(main(*args))


if __name__ == "__main__":
    raise SystemExit(main())
