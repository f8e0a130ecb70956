"""OpenCL plumbing: device choice, the program loader, and the context that owns device memory."""

from sdfserver.gpu.runtimes import register_cpu_runtimes

register_cpu_runtimes()  # before the first OpenCL call of the process: the ICD loader reads it once

from sdfserver.gpu.context import GpuContext  # noqa: E402
from sdfserver.gpu.device import choose_device, describe_devices, usable_devices  # noqa: E402

__all__ = ["GpuContext", "choose_device", "describe_devices", "usable_devices"]
