"""``sdfserver serve``: one uvicorn process, one engine, one device.

Flags are generated from the Settings fields (``--max-request-bytes`` for
``max_request_bytes``) and override ``SDFSERVER_*`` environment variables.
Scale with one process per device, never with uvicorn workers on one device; ``--fronts N``
adds processes that parse the hot requests' HTTP for this one (``fronts.py``).
"""

from __future__ import annotations

import argparse
import logging
import sys
import typing
from typing import Any

from pydantic import ValidationError

from sdfserver.errors import SdfServerError
from sdfserver.settings import Settings, log_unknown_environment


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
    import uvicorn

    from sdfserver.api.app import build_engine, create_app
    from sdfserver.api.auth import is_loopback, parse_keys
    from sdfserver.api.coalesce import CoalescingHttpToolsProtocol
    from sdfserver.api.durability import open_journal, restore
    from sdfserver.api.fronts import FrontedServer, FrontPool
    from sdfserver.api.logs import configure_logging
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
    journal = None
    try:
        journal = open_journal(settings)
        data_dir_lock = lock_data_dir(journal.storage.data_dir) if journal is not None else None
        engine = build_engine(settings, journal=journal, metrics=EngineMetrics())
    except SdfServerError as exc:  # no OpenCL device, unusable data directory: say so and stop
        print(f"sdfserver serve: {exc}", file=sys.stderr)
        if journal is not None:
            journal.close()
        return 1
    logging.getLogger("sdfserver").info("device: %s", engine.gpu.device_name)
    if journal is not None:
        logging.getLogger("sdfserver").info("data directory: %s (sync %s)", journal.storage.data_dir,
                                            "on" if settings.sync else "OFF")
        restore(engine, journal)
    app = create_app(settings, engine, freeze_gc=True)
    app.state.journal = journal
    try:
        config = uvicorn.Config(app, host=settings.host, port=settings.port, log_config=log_config,
                                http=CoalescingHttpToolsProtocol,  # one send per answer, not one per head and body
                                log_level=settings.log_level, access_log=settings.access_log,
                                ws_max_size=settings.max_request_bytes, timeout_graceful_shutdown=5)
        server = FrontedServer(config, FrontPool(settings, app.state)) if settings.fronts else uvicorn.Server(config)
        try:
            server.run()
        except KeyboardInterrupt:
            pass
        if not server.started:
            return 3  # uvicorn's start-up failure status, as uvicorn.run exits with
    finally:
        if journal is not None:
            journal.close()
        if data_dir_lock is not None:
            data_dir_lock.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
