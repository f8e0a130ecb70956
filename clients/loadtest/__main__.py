"""``python clients/loadtest [options]`` (or ``python -m loadtest`` with ``clients/`` on the path)."""

import sys
from pathlib import Path

if __package__ in (None, ""):  # run as a directory: the package's parent goes on the path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from loadtest.cli import main  # noqa: E402

if __name__ == "__main__":
    raise SystemExit(main())
