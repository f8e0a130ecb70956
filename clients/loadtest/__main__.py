"""``python clients/loadtest [options]`` (or ``python -m loadtest`` with ``clients/`` on the path)."""

import sys
from pathlib import Path

if __package__ in (None, ""):  # run as a directory: the package's parent goes on the path, and
    # the Python client's checkout where it is not installed (the GPU hosts run from the tree)
    clients = Path(__file__).resolve().parents[1]
    sys.path[:0] = [str(clients), str(clients / "python")]

from loadtest.cli import main  # noqa: E402

if __name__ == "__main__":
    raise SystemExit(main())
