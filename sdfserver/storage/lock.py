"""One server per data directory: an advisory lock held for the life of `sdfserver serve`.

Two servers appending to the same write-ahead logs would interleave versions and corrupt them;
the second one must refuse to start instead.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
from typing import IO

from sdfserver.errors import StorageError


def lock_data_dir(data_dir: Path) -> IO[str]:
    """Take ``data_dir/serve.lock`` exclusively; the returned file must stay open while serving."""
    path = Path(data_dir) / "serve.lock"
    handle = try_lock(path)
    if handle is None:
        holder = path.read_text().strip() or "another process"
        raise StorageError(f"data directory {data_dir} is in use by {holder}; "
                           "give each server its own --data-dir")
    handle.seek(0)
    handle.truncate()
    handle.write(f"sdfserver serve pid {os.getpid()}\n")
    handle.flush()
    return handle


def try_lock(path: Path) -> IO[str] | None:
    """Take ``path`` exclusively if no other process holds it (the returned file keeps it), else None."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    handle = open(path, "a+")
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.close()
        return None
    return handle
