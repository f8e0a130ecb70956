"""What every `sdfserver bench` command shares: a line on stderr for each step and each
measurement, so a slow device shows it is working; results that outlive a stop (every
measurement is written to the results file as it is taken, and Ctrl-C or SIGTERM ends the run
with the tables of what was measured); and the commit that was measured, so a figure can name it.

A leaf: it imports nothing of sdfserver, so ``sdfserver.render.bench`` can use it too."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterator

INTERRUPTED_EXIT = 130  # as a shell reports a command ended by SIGINT


def progress(message: str) -> None:
    print(f"[bench] {message}", file=sys.stderr, flush=True)


def source_commit() -> str | None:
    """The commit of the checkout this code runs from; None where git or its history is missing
    (a tree copied to another machine without ``.git``)."""
    root = Path(__file__).resolve().parents[2]
    try:
        done = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                              timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return (done.stdout.strip() or None) if done.returncode == 0 else None


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


class Outcome:
    """How a run inside ``stoppable`` ended: its exit ``status``."""

    status = 0


@contextlib.contextmanager
def stoppable(results: "Results", kept: str) -> Iterator[Outcome]:
    """Measure inside; a stop (Ctrl-C or SIGTERM) marks ``results`` interrupted, says that
    ``kept`` (the files and tables that hold what was measured), and sets the exit status to
    INTERRUPTED_EXIT, so the caller still writes out what it has."""
    outcome = Outcome()
    with sigterm_interrupts():
        try:
            yield outcome
        except KeyboardInterrupt:
            results.data["interrupted"] = True
            progress(f"interrupted: {kept}")
            outcome.status = INTERRUPTED_EXIT


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


__all__ = ["INTERRUPTED_EXIT", "Outcome", "Results", "progress", "sigterm_interrupts", "source_commit", "stoppable"]
