"""``sdfserver serve``: one uvicorn process, one engine, one device.

Flags are generated from the Settings fields (``--max-request-bytes`` for
``max_request_bytes``) and override ``SDFSERVER_*`` environment variables.
Scale with one process per device, never with uvicorn workers on one device; ``--fronts N``
adds processes that parse the hot requests' HTTP for this one (``fronts.py``).

Start-up in order: the port (``port.py``: a second server stops here), the data directory, the
device, the stored worlds, the engine's warm-up; only then does it listen. What fails on the way
is said in one line, with exit status 1. A dead engine thread ends the server, also with 1.
"""

from __future__ import annotations

import argparse
import logging
import socket
import sys
import typing
from typing import Any

from pydantic import ValidationError

from sdfserver.errors import NoOpenCLDevice, SdfServerError
from sdfserver.settings import Settings, log_unknown_environment

DEVICE_ADVICE = "`sdfserver devices` lists the usable OpenCL devices and --device picks one"


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


def main(argv: list[str] | None = None) -> int:
    from sdfserver.api.app import build_engine
    from sdfserver.api.auth import is_loopback, parse_keys
    from sdfserver.api.durability import open_journal
    from sdfserver.api.logs import configure_logging
    from sdfserver.api.port import cannot_listen, hold_port
    from sdfserver.engine import EngineMetrics
    from sdfserver.storage.lock import lock_data_dir

    try:
        settings = settings_from(list(sys.argv[1:] if argv is None else argv))
    except ValidationError as exc:
        print(f"sdfserver serve: invalid settings:\n{exc}", file=sys.stderr)
        return 2
    log_config = configure_logging(settings)
    log_unknown_environment()
    # The event loop and the engine thread share the GIL: under load, every time the engine
    # blocks (queue.finish, a read, a log write) it waits up to this long to get it back.
    sys.setswitchinterval(settings.switch_interval_ms / 1e3)
    try:
        keys = parse_keys(settings.api_keys, settings.api_key_file)
    except SdfServerError as exc:
        print(f"sdfserver serve: {exc}", file=sys.stderr)
        return 2
    if not keys and not is_loopback(settings.host):
        print(f"sdfserver serve: refusing to listen on {settings.host} with no API keys configured; set "
              "SDFSERVER_API_KEYS / --api-keys or --api-key-file, or listen on 127.0.0.1", file=sys.stderr)
        return 2
    try:  # before the warm-up: a second server on this port stops at once
        held = hold_port(settings.host, settings.port)
    except OSError as exc:
        print(f"sdfserver serve: {cannot_listen(settings.host, settings.port, exc)}", file=sys.stderr)
        return 1
    journal = data_dir_lock = engine = None
    try:
        try:
            journal = open_journal(settings)
            data_dir_lock = lock_data_dir(journal.storage.data_dir) if journal is not None else None
            engine = build_engine(settings, journal=journal, metrics=EngineMetrics())
        except SdfServerError as exc:  # no OpenCL device, unusable data directory: say so and stop
            advice = f" ({DEVICE_ADVICE})" if isinstance(exc, NoOpenCLDevice) else ""
            print(f"sdfserver serve: {exc}{advice}", file=sys.stderr)
            return 1
        return _serve(settings, engine, journal, held, log_config)
    finally:
        if engine is not None:
            engine.stop(timeout_s=5.0)  # stopped already unless it never served
        if journal is not None:
            journal.close()
        if data_dir_lock is not None:
            data_dir_lock.close()
        held.close()


def _serve(settings: Settings, engine: Any, journal: Any, held: socket.socket, log_config: Any) -> int:
    """Warm the engine up, then listen; the exit status."""
    import uvicorn

    from sdfserver.api.app import create_app
    from sdfserver.api.coalesce import CoalescingHttpToolsProtocol
    from sdfserver.api.durability import restore
    from sdfserver.api.fronts import FrontedServer, FrontPool
    from sdfserver.api.port import OneProcessServer, listener

    log = logging.getLogger("sdfserver")
    log.info("device: %s", engine.gpu.device_name)
    if journal is not None:
        log.info("data directory: %s (sync %s)", journal.storage.data_dir, "on" if settings.sync else "OFF")
        restore(engine, journal)
    server: uvicorn.Server | None = None
    died: list[str] = []

    def on_death(reason: str) -> None:  # the engine thread, as it dies: no serving without it
        died.append(reason)
        if server is not None:
            server.should_exit = True

    engine.start(warm_up=settings.warm_up, on_death=on_death)
    try:
        failure = engine.wait_started()  # listen only once the engine has shown it can serve
    except KeyboardInterrupt:
        return 130
    if failure is not None:
        print(f"sdfserver serve: {failure}; {DEVICE_ADVICE}", file=sys.stderr)
        return 1
    app = create_app(settings, engine, freeze_gc=True)
    app.state.journal = journal
    config = uvicorn.Config(app, host=settings.host, port=held.getsockname()[1], log_config=log_config,
                            http=CoalescingHttpToolsProtocol,  # one send per answer, not one per head and body
                            log_level=settings.log_level, access_log=settings.access_log,
                            ws_max_size=settings.max_request_bytes, timeout_graceful_shutdown=5)
    if settings.fronts:
        server = FrontedServer(config, FrontPool(settings, app.state, config.port))
        sockets = None
    else:
        server = OneProcessServer(config)
        sockets = [listener(held)]
    if died:  # before the server existed to be told
        server.should_exit = True
    try:
        server.run(sockets=sockets)
    except KeyboardInterrupt:
        pass
    finally:
        for sock in sockets or ():
            sock.close()
    if died:
        print(f"sdfserver serve: {died[0]}; exiting, so that a supervisor can start it again", file=sys.stderr)
        return 1
    if not server.started:
        return 3  # uvicorn's start-up failure status, as uvicorn.run exits with
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
