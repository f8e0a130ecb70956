"""`sdfserver bench [render | seed | metrics] [options]`: which benchmark a command line asks for.

Each benchmark parses its own arguments (``--help`` after its name lists them). Without a name,
`sdfserver bench` runs ``sections`` (the dissertation's single-chunk tables, whole worlds, the
incremental brush, accuracy and anchors). A benchmark's module is imported only when asked for:
`render` lives beside the renderer it measures and needs this package's leaves, and `seed` needs
matplotlib's plots only where it is installed.
"""

from __future__ import annotations

import importlib
import sys

BENCHMARKS = {
    "render": "sdfserver.render.bench",  # the dissertation's benchmark mode (§3.5): edits while rendering
    "seed": "sdfserver.bench.seed.cli",  # the dissertation's chapter 4, every table and figure
    "metrics": "sdfserver.bench.metrics",  # Manhattan and Euclidean, unsigned and signed
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    name = argv[0] if argv and argv[0] in BENCHMARKS else None
    module = importlib.import_module(BENCHMARKS[name] if name else "sdfserver.bench.sections")
    return int(module.main(argv[1:] if name else argv) or 0)


if __name__ == "__main__":
    raise SystemExit(main())
