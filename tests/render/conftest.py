import pytest

from sdfserver.gpu import GpuContext, describe_devices


def pytest_generate_tests(metafunc):
    if "gpu" in metafunc.fixturenames:
        devices = [line.split(":", 1)[0] for line in describe_devices()]
        metafunc.parametrize("gpu", devices, indirect=True, scope="module")


_contexts: dict[str, GpuContext] = {}


@pytest.fixture(scope="module")
def gpu(request):
    """A GpuContext on each OpenCL device present (PoCL's CPU device in CI)."""
    spec = request.param
    if spec not in _contexts:
        _contexts[spec] = GpuContext.create(spec)
    return _contexts[spec]
