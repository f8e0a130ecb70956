"""The one loader of device code.

Every kernel lives in ``kernels/*.cl`` with shared definitions in
``kernels/include``. Programs are built with ``-I kernels/include`` and
``-D NAME=value`` options, memoized per (context, file, options), and left to
pyopencl's disk cache, which follows ``#include``. A failed build raises
KernelBuildError with the file, the options and the build log.

Every build also gets the device's own defines (``device_defines``): what the
device can do beyond OpenCL C, e.g. NVIDIA sm_90's packed 16-bit min.

Kernels come with their by-value argument types declared to pyopencl, read from the
program's own argument info (``-cl-kernel-arg-info``): pyopencl then packs scalars with
``struct`` instead of probing each argument, which took ~50 us of the engine thread per
launch of an 11-argument kernel on the H200 host (82 us on PoCL, against ~1 us declared).
"""

from __future__ import annotations

import logging
import threading
import warnings
from pathlib import Path

import pyopencl as cl
from pyopencl import cltypes

from sdfserver.errors import KernelBuildError

log = logging.getLogger(__name__)

KERNEL_DIR = Path(__file__).resolve().parents[2] / "kernels"
INCLUDE_DIR = KERNEL_DIR / "include"


def _define(name: str, value: int | str) -> str:
    if not name.isidentifier():
        raise ValueError(f"bad macro name {name!r}")
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise TypeError(f"macro {name} must be int or str, got {type(value).__name__}")
    return f"-D{name}={value}"


def device_defines(device: cl.Device) -> dict[str, int]:
    """Defines that describe the device to kernels (kernels/include/sdf_common.h lists them)."""
    defines = {"SDF_PTX_16X2": 0, "SDF_NVIDIA": 0}
    if "NVIDIA" in device.platform.name.upper():
        defines["SDF_NVIDIA"] = 1  # NVIDIA's OpenCL compiles inline PTX
        try:
            major = int(device.compute_capability_major_nv)
        except (cl.Error, AttributeError):  # no cl_nv_device_attribute_query
            major = 0
        # PTX min.u16x2 is one instruction from sm_90 on.
        defines["SDF_PTX_16X2"] = int(major >= 9)
    return defines


class ProgramCache:
    """Builds and memoizes programs for one OpenCL context."""

    def __init__(self, context: cl.Context, defines: dict[str, int] | None = None):
        self._context = context
        self.device_defines = dict(defines or {})
        self._programs: dict[tuple[str, tuple[str, ...]], cl.Program] = {}
        self._kernels: dict[tuple, cl.Kernel] = {}
        self._lock = threading.Lock()

    def __len__(self) -> int:
        """Programs built so far."""
        return len(self._programs)

    def _options(self, defines: dict[str, int | str]) -> tuple[str, ...]:
        merged = {**self.device_defines, **defines}
        return tuple(sorted(_define(k, v) for k, v in merged.items()))

    def get(self, filename: str, **defines: int | str) -> cl.Program:
        options = self._options(defines)
        key = (filename, options)
        with self._lock:
            program = self._programs.get(key)
            if program is None:
                program = self._build(filename, options)
                self._programs[key] = program
            return program

    def kernel(self, filename: str, name: str, **defines: int | str) -> cl.Kernel:
        """A memoized kernel object; only the thread that owns the device may call it."""
        # Keyed on the defines as given: building the option strings cost ~5 us a launch.
        key = (filename, name, *defines.items())
        kernel = self._kernels.get(key)
        if kernel is None:
            kernel = cl.Kernel(self.get(filename, **defines), name)
            declare_scalar_args(kernel)
            self._kernels[key] = kernel
        return kernel

    def _build(self, filename: str, defines: tuple[str, ...]) -> cl.Program:
        path = KERNEL_DIR / filename
        source = path.read_text()
        options = [f"-I{INCLUDE_DIR}", "-cl-kernel-arg-info", *defines]
        try:
            # A successful build with a non-empty log (NVIDIA notes inlining) is not a
            # failure: keep the log for debugging instead of raising a warning.
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", cl.CompilerWarning)
                program = cl.Program(self._context, source).build(options=options)
        except cl.RuntimeError as exc:
            raise KernelBuildError(str(path), options, str(exc)) from exc
        for w in caught:
            log.debug("build of %s %s: %s", filename, " ".join(defines), w.message)
        return program


def scalar_arg_dtypes(kernel: cl.Kernel) -> list | None:
    """Each argument's dtype (None for buffers and local memory), from the kernel's argument
    info; None when the driver gives none or names a type cltypes does not know."""
    dtypes = []
    try:
        for i in range(kernel.num_args):
            if kernel.get_arg_info(i, cl.kernel_arg_info.ADDRESS_QUALIFIER) != cl.kernel_arg_address_qualifier.PRIVATE:
                dtypes.append(None)
                continue
            dtype = getattr(cltypes, kernel.get_arg_info(i, cl.kernel_arg_info.TYPE_NAME).strip(), None)
            if dtype is None:
                return None
            dtypes.append(dtype)
    except cl.Error:  # CL_KERNEL_ARG_INFO_NOT_AVAILABLE
        return None
    return dtypes


def declare_scalar_args(kernel: cl.Kernel) -> None:
    dtypes = scalar_arg_dtypes(kernel)
    if dtypes is None:
        log.debug("no argument info for kernel %s: its arguments are set the slow way", kernel.function_name)
        return
    kernel.set_scalar_arg_dtypes(dtypes)
