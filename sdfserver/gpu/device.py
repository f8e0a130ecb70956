"""Choosing the OpenCL device, and proving it works before it is used.

A device spec is empty (prefer a GPU, fall back to any CPU device such as
PoCL's or Intel's), an index into the flattened device list (``"0"``), or a
case-insensitive substring of ``"<platform> / <device>"`` (``"nvidia"``,
``"pocl"``, ``"H100"``).

A device that is listed is not yet a device that works: a CPU runtime whose
compiler does not know the host CPU lists its device and then fails every
build. So each device is proven once a process (``prove``: build a tiny kernel,
run it, read the result back). Choosing with an empty spec skips devices that
fail, with one warning line each that names the device and the first lines of
its error; a spec that names a failing device is an error.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

import numpy as np
import pyopencl as cl

from sdfserver.errors import NoOpenCLDevice

log = logging.getLogger(__name__)

HOW_TO_FIX = (
    "Install the CPU OpenCL runtimes with `pip install -e '.[cpu]'` (PoCL and Intel's), install "
    "Debian's `pocl-opencl-icd`, or register the NVIDIA OpenCL driver: `mkdir -p "
    "/etc/OpenCL/vendors && echo libnvidia-opencl.so.1 > /etc/OpenCL/vendors/nvidia.icd` "
    "(deploy/README.md shows how). `sdfserver devices` lists what is found and why a device "
    "cannot be used."
)

_PROOF_SOURCE = """
__kernel void sdf_proof(__global uint *out, uint k)
{
    const uint i = get_global_id(0);
    out[i] = i * k + 1u;
}
"""
_PROOF_ITEMS = 64
_PROOF_K = 3


@dataclass(frozen=True)
class DeviceProof:
    usable: bool
    reason: str = ""  # why not, when not usable: the error's first lines


_proofs: dict[tuple[str, str, str], DeviceProof] = {}
_warned: set[tuple[str, str, str]] = set()


def _key(device: cl.Device) -> tuple[str, str, str]:
    return (device.platform.name, device.name, device.version)


def _first_lines(text: str, lines: int = 3) -> str:
    kept = [line.strip() for line in str(text).splitlines() if line.strip()]
    return " | ".join(kept[:lines]) or "no message"


def prove(device: cl.Device) -> DeviceProof:
    """Build and run a tiny kernel on ``device``; memoized per process."""
    key = _key(device)
    proof = _proofs.get(key)
    if proof is None:
        proof = _proofs[key] = _run_proof(device)
    return proof


def _run_proof(device: cl.Device) -> DeviceProof:
    try:
        context = cl.Context([device])
        queue = cl.CommandQueue(context)
        with warnings.catch_warnings():  # a runtime's notes on a successful build are no failure
            warnings.simplefilter("ignore", cl.CompilerWarning)
            program = cl.Program(context, _PROOF_SOURCE).build()
        out = np.zeros(_PROOF_ITEMS, dtype=np.uint32)
        buffer = cl.Buffer(context, cl.mem_flags.WRITE_ONLY, out.nbytes)
        program.sdf_proof(queue, (_PROOF_ITEMS,), None, buffer, np.uint32(_PROOF_K))
        cl.enqueue_copy(queue, out, buffer, is_blocking=True)
        buffer.release()
    except Exception as exc:  # a build error, a driver error, a runtime that cannot load
        return DeviceProof(False, f"{type(exc).__name__}: {_first_lines(exc)}")
    expected = np.arange(_PROOF_ITEMS, dtype=np.uint32) * _PROOF_K + 1
    if not np.array_equal(out, expected):
        return DeviceProof(False, "a test kernel ran but wrote wrong results")
    return DeviceProof(True)


def _all_devices() -> list[cl.Device]:
    try:
        platforms = cl.get_platforms()
    except cl.LogicError as exc:  # pyopencl raises this for "no platforms" (-1001)
        raise NoOpenCLDevice(f"No OpenCL platform found ({exc}). {HOW_TO_FIX}") from exc
    devices = []
    for platform in platforms:
        try:
            devices.extend(platform.get_devices())
        except cl.Error as exc:  # a platform with no device answers DEVICE_NOT_FOUND
            log.debug("OpenCL platform %s lists no device: %s", platform.name, exc)
    if not devices:
        raise NoOpenCLDevice(f"OpenCL platforms exist but expose no device. {HOW_TO_FIX}")
    return devices


def label(device: cl.Device) -> str:
    return f"{device.platform.name.strip()} / {device.name.strip()}"


def describe_devices() -> list[str]:
    """One line per visible device, numbered as a spec index would pick it, usable or not."""
    lines = []
    for i, device in enumerate(_all_devices()):
        proof = prove(device)
        state = "usable" if proof.usable else f"NOT usable: {proof.reason}"
        lines.append(f"{i}: {label(device)} ({state})")
    return lines


def usable_devices() -> list[cl.Device]:
    """Every device that passes its proof, GPUs first, each in the loader's order; one warning
    line for each that does not."""
    usable = []
    for device in _all_devices():
        proof = prove(device)
        if proof.usable:
            usable.append(device)
        elif _key(device) not in _warned:
            _warned.add(_key(device))
            log.warning("skipping OpenCL device %s: %s", label(device), proof.reason)
    return sorted(usable, key=lambda d: not d.type & cl.device_type.GPU)


def choose_device(spec: str | None = None) -> cl.Device:
    spec = (spec or "").strip()
    if not spec:
        usable = usable_devices()
        if not usable:
            raise NoOpenCLDevice(
                f"No OpenCL device works: {'; '.join(describe_devices())}. {HOW_TO_FIX}")
        return usable[0]
    devices = _all_devices()
    if spec.isdigit():
        index = int(spec)
        if index >= len(devices):
            raise NoOpenCLDevice(
                f"Device index {index} out of range; devices: {describe_devices()}"
            )
        return _proven(devices[index])
    matches = [d for d in devices if spec.lower() in label(d).lower()]
    if not matches:
        raise NoOpenCLDevice(f"No OpenCL device matches {spec!r}; devices: {describe_devices()}")
    working = [d for d in matches if prove(d).usable]
    return working[0] if working else _proven(matches[0])


def _proven(device: cl.Device) -> cl.Device:
    proof = prove(device)
    if not proof.usable:
        raise NoOpenCLDevice(f"OpenCL device {label(device)} cannot be used: {proof.reason}. {HOW_TO_FIX}")
    return device
