"""The Python tools' way to start a server and wait for it: the contract of ``serve_build`` in
tools/serve_build.sh, which the shell scripts source.

The server is checkout ``root``'s ``sdfserver serve`` with that checkout's code first on
PYTHONPATH, so an older build runs with this checkout's clients and only the server differs.
It is ready once ``/readyz`` answers; one that exits first, or is not ready within ``ready_s``,
ends the tool with a message that names its log. On leaving the block the server gets SIGTERM,
as an operator's stop would, and SIGKILL if it has not stopped a minute later.

    from serve_build import serve_build   # tools/ is sys.path[0] for `python3 tools/NAME.py`

    with serve_build(ROOT, log, 8765, data_dir, ["--workers", "1"], device="nvidia") as server:
        ...   # http://127.0.0.1:8765
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator, Sequence
from pathlib import Path

SERVE = ("-m", "sdfserver", "serve")


@contextlib.contextmanager
def serve_build(root: str | Path, log: str | Path, port: int, data_dir: str | Path, flags: Sequence[str] = (), *,
                device: str | None = "nvidia", entry: Sequence[str] = SERVE, ready_s: float = 120.0,
                keep_data: bool = False) -> Iterator[subprocess.Popen]:
    """Serve checkout ``root`` on ``port`` until the block ends. ``device`` None or empty passes
    no ``--device`` (the server's own choice, or flags such as ``--devices`` that name them);
    ``entry`` is what the interpreter runs (``-c CODE`` for a server with something installed
    first); ``data_dir`` is emptied first unless ``keep_data``."""
    root = Path(root).resolve()
    if not keep_data:
        shutil.rmtree(data_dir, ignore_errors=True)
    command = [sys.executable, *entry, *(["--device", device] if device else []), "--port", str(port),
               "--data-dir", str(data_dir), *flags]
    env = dict(os.environ, PYTHONPATH=f"{root}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    with open(log, "w") as output:
        server = subprocess.Popen(command, env=env, cwd=root, stdout=output, stderr=subprocess.STDOUT)
    try:
        wait_ready(server, f"http://127.0.0.1:{port}", ready_s, f"the server of {root} (log: {log})")
        yield server
    finally:
        stop(server)


def wait_ready(server: subprocess.Popen, url: str, ready_s: float, name: str) -> None:
    deadline = time.monotonic() + ready_s
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(url + "/readyz", timeout=2):
                return
        except OSError:  # refused while it starts, or 503 until it is ready
            if server.poll() is not None:
                raise SystemExit(f"{name} exited ({server.returncode}) before it was ready") from None
            time.sleep(0.25)
    raise SystemExit(f"{name} did not answer /readyz in {ready_s:.0f} s")


def stop(server: subprocess.Popen) -> None:
    if server.poll() is not None:
        return
    server.terminate()
    try:
        server.wait(60)
    except subprocess.TimeoutExpired:
        server.kill()
        server.wait()
