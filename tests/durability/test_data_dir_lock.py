"""A second server on the same data directory refuses to start, saying which process holds it."""

import os
import subprocess
import sys

import pytest

from sdfserver.errors import StorageError
from sdfserver.storage.lock import lock_data_dir

from server_process import checkout_env


def test_lock_is_exclusive_and_released(tmp_path):
    held = lock_data_dir(tmp_path)
    with pytest.raises(StorageError, match=f"pid {os.getpid()}"):
        lock_data_dir(tmp_path)
    held.close()
    lock_data_dir(tmp_path).close()


def test_second_serve_on_a_held_directory_exits(tmp_path):
    held = lock_data_dir(tmp_path)
    try:
        env = checkout_env()
        proc = subprocess.run([sys.executable, "-m", "sdfserver", "serve", "--port", "0", "--data-dir", str(tmp_path)],
                              env=env, capture_output=True, text=True, timeout=120)
    finally:
        held.close()
    assert proc.returncode == 1
    assert "is in use by" in proc.stderr and "--data-dir" in proc.stderr
