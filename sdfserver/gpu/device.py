"""Choosing the OpenCL device.

A device spec is empty (prefer a GPU, fall back to any CPU device such as
PoCL's), an index into the flattened device list (``"0"``), or a
case-insensitive substring of ``"<platform> / <device>"`` (``"nvidia"``,
``"pocl"``, ``"H100"``).
"""

from __future__ import annotations

import pyopencl as cl

from sdfserver.errors import NoOpenCLDevice

_HOW_TO_FIX = (
    "Install PoCL's CPU device with `pip install 'pyopencl[pocl]'`, or register the "
    "NVIDIA OpenCL driver: `mkdir -p /etc/OpenCL/vendors && echo libnvidia-opencl.so.1 "
    "> /etc/OpenCL/vendors/nvidia.icd` (deploy/README.md shows how)."
)


def _all_devices() -> list[cl.Device]:
    try:
        platforms = cl.get_platforms()
    except cl.LogicError as exc:  # pyopencl raises this for "no platforms" (-1001)
        raise NoOpenCLDevice(f"No OpenCL platform found ({exc}). {_HOW_TO_FIX}") from exc
    devices = [device for platform in platforms for device in platform.get_devices()]
    if not devices:
        raise NoOpenCLDevice(f"OpenCL platforms exist but expose no device. {_HOW_TO_FIX}")
    return devices


def _label(device: cl.Device) -> str:
    return f"{device.platform.name.strip()} / {device.name.strip()}"


def describe_devices() -> list[str]:
    """One line per visible device, numbered as a spec index would pick it."""
    return [f"{i}: {_label(d)}" for i, d in enumerate(_all_devices())]


def choose_device(spec: str | None = None) -> cl.Device:
    devices = _all_devices()
    spec = (spec or "").strip()
    if not spec:
        gpus = [d for d in devices if d.type & cl.device_type.GPU]
        return (gpus or devices)[0]
    if spec.isdigit():
        index = int(spec)
        if index >= len(devices):
            raise NoOpenCLDevice(
                f"Device index {index} out of range; devices: {describe_devices()}"
            )
        return devices[index]
    matches = [d for d in devices if spec.lower() in _label(d).lower()]
    if not matches:
        raise NoOpenCLDevice(f"No OpenCL device matches {spec!r}; devices: {describe_devices()}")
    return matches[0]
