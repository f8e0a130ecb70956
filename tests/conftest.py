"""Every server a test starts keeps its worlds in a throw-away data directory, never in ./data.

This session-wide directory is only the fallback. Worlds are durable, so a fixture that starts a
server passes ``--data-dir`` with a directory of its own: servers sharing one would restore each
other's worlds (and run side by side on the same files).
"""

import atexit
import os
import shutil
import tempfile

_DATA_DIR = tempfile.mkdtemp(prefix="sdfserver-tests-")
os.environ.setdefault("SDFSERVER_DATA_DIR", _DATA_DIR)
atexit.register(shutil.rmtree, _DATA_DIR, True)
