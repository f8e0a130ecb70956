"""Session-wide test set-up: a throw-away data directory and the OpenCL devices tests run on.

Every server a test starts keeps its worlds in a throw-away data directory, never in ./data.
This session-wide directory is only the fallback. Worlds are durable, so a fixture that starts a
server passes ``--data-dir`` with a directory of its own: servers sharing one would restore each
other's worlds (and run side by side on the same files).

Device tests run on the first device that passes its proof (``sdfserver.gpu.usable_devices``:
a GPU if one works, else a CPU runtime), the device a server started by a test would choose.
``SDF_TEST_ALL_DEVICES=1`` runs them on every usable device instead.
"""

import atexit
import os
import shutil
import tempfile

import pytest

_DATA_DIR = tempfile.mkdtemp(prefix="sdfserver-tests-")
os.environ.setdefault("SDFSERVER_DATA_DIR", _DATA_DIR)
atexit.register(shutil.rmtree, _DATA_DIR, True)

ALL_DEVICES_VARIABLE = "SDF_TEST_ALL_DEVICES"


def _test_devices():
    from sdfserver.errors import NoOpenCLDevice
    from sdfserver.gpu import usable_devices

    try:
        devices = usable_devices()
    except NoOpenCLDevice:
        return []
    return devices if os.environ.get(ALL_DEVICES_VARIABLE) == "1" else devices[:1]


TEST_DEVICES = _test_devices()


def pytest_report_header(config):
    from sdfserver.gpu.device import label

    names = ", ".join(label(d) for d in TEST_DEVICES) or "none usable"
    return f"sdfserver test devices ({ALL_DEVICES_VARIABLE}=1 for all): {names}"


_contexts: dict = {}


@pytest.fixture(scope="session", params=TEST_DEVICES, ids=lambda d: d.name.strip().replace(" ", "_"))
def gpu(request):
    """A GpuContext on each test device, shared by the whole session."""
    from sdfserver.gpu import GpuContext

    if request.param not in _contexts:
        _contexts[request.param] = GpuContext(request.param)
    return _contexts[request.param]
