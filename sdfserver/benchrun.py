"""What `sdfserver bench` and `sdfserver bench render` share: a line on stderr for each step and
each measurement, so a slow device shows it is working, and results that outlive a stop: every
measurement is written to the ``--json`` file as it is taken, and Ctrl-C or SIGTERM ends the run
with the tables of what was measured."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
from pathlib import Path
from typing import Any, Iterator

INTERRUPTED_EXIT = 130  # as a shell reports a command ended by SIGINT


def progress(message: str) -> None:
    print(f"[bench] {message}", file=sys.stderr, flush=True)


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


@contextlib.contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt, so a run stopped either way keeps what it measured."""
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class Results:
    """A benchmark's results, written to ``path`` (if any) after each measurement."""

    def __init__(self, data: dict[str, Any], path: str | None):
        self.data, self.path = data, path

    def rows(self, section: str) -> list[dict]:
        return self.data.setdefault(section, [])

    def add(self, section: str, row: dict, summary: str) -> None:
        self.rows(section).append(row)
        progress(f"{section}: {summary}")
        self.save()

    def save(self) -> None:
        """Replaces the file whole, so a stop while writing leaves the previous measurements."""
        if not self.path:
            return
        path = Path(self.path)
        partial = path.with_name(path.name + ".partial")
        partial.write_text(json.dumps(self.data, indent=1))
        os.replace(partial, path)


__all__ = ["INTERRUPTED_EXIT", "Results", "progress", "sigterm_interrupts"]
