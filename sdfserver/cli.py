"""The `sdfserver` command: `serve` runs the server, `bench` the benchmark, `devices` lists the
OpenCL devices; `sdfserver --version` prints the version.

Each subcommand parses its own arguments, so `sdfserver serve --help` and
`sdfserver bench --help` list them.
"""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    commands = {
        "serve": "sdfserver.api.server",
        "bench": "sdfserver.bench.cli",
        "devices": None,
    }
    if argv[:1] in (["--version"], ["-V"]):
        from sdfserver import __version__

        print(f"sdfserver {__version__}")
        return 0
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in commands:
        print("usage: sdfserver {serve,bench,devices} [options] | sdfserver --version\n"
              "  serve    run the HTTP/WebSocket server\n"
              "  bench    run the benchmark tables\n"
              "  devices  list the OpenCL devices, each usable or not and why", file=sys.stderr)
        return 0 if argv and argv[0] in ("-h", "--help") else 2
    if argv[0] == "devices":
        from sdfserver.errors import NoOpenCLDevice
        from sdfserver.gpu import describe_devices

        try:
            listing = describe_devices()
        except NoOpenCLDevice as exc:
            print(exc, file=sys.stderr)
            return 1
        print("\n".join(listing))
        return 0 if any(line.endswith("(usable)") for line in listing) else 1
    import importlib

    module = importlib.import_module(commands[argv[0]])
    return int(module.main(argv[1:]) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
