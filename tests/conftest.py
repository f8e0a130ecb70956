"""Every server a test starts keeps its worlds in a throw-away data directory, never in ./data."""

import atexit
import os
import shutil
import tempfile

_DATA_DIR = tempfile.mkdtemp(prefix="sdfserver-tests-")
os.environ.setdefault("SDFSERVER_DATA_DIR", _DATA_DIR)
atexit.register(shutil.rmtree, _DATA_DIR, True)
