"""OpenCL plumbing: device choice, the program loader, and the context that owns device memory."""

from sdfserver.gpu.context import GpuContext
from sdfserver.gpu.device import choose_device, describe_devices, usable_devices

__all__ = ["GpuContext", "choose_device", "describe_devices", "usable_devices"]
