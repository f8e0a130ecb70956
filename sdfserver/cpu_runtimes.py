"""Registering Intel's CPU OpenCL runtime, installed from PyPI, with the OpenCL ICD loader.

The ``cpu`` extra installs two CPU OpenCL runtimes: PoCL (bundled with pyopencl's wheel, found
by the loader on its own) and Intel's (``intel-opencl-rt``). PoCL's bundled LLVM predates some
CPUs and then cannot build any kernel ("unknown target CPU"); Intel's runtime builds on any
x86-64 CPU with SSE4.2, AMD's included. Its wheel cannot register itself: the ``.icd`` file it
installs names a placeholder path, and the libraries it needs (``intel-cmplr-lib-rt``'s
``libimf.so``, ``libsvml.so``, ...) sit in ``<venv>/lib``, where the dynamic linker does not
look. So before the first OpenCL call in the process:

* those libraries are loaded by absolute path with ``RTLD_GLOBAL``, so that the loader's later
  ``dlopen`` of ``libintelocl.so`` finds them already resolved;
* unless the user set ``OCL_ICD_VENDORS`` (then theirs is used as it is), a vendors directory
  of our own is written: every ``.icd`` file of ``/etc/OpenCL/vendors`` (so a GPU driver stays
  visible) plus one naming ``libintelocl.so`` by its absolute path. ``OCL_ICD_VENDORS`` points
  the loader at it; child processes inherit it.

The ICD loader reads ``OCL_ICD_VENDORS`` once, at the first OpenCL call of the process, and
pyopencl reads ``PYOPENCL_NO_CACHE`` when it is imported, which is why the ``sdfserver`` package
calls ``register_cpu_runtimes`` when it is imported, before any of its modules imports pyopencl.
This module imports nothing of pyopencl.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import sys
from pathlib import Path

log = logging.getLogger(__name__)

SYSTEM_VENDORS_DIR = Path("/etc/OpenCL/vendors")
INTEL_ICD_NAME = "intel-cpu.icd"
# intel-cmplr-lib-rt's libraries that libintelocl.so links against, each after what it needs.
INTEL_COMPILER_LIBRARIES = ("libintlc.so.5", "libirng.so", "libsvml.so", "libimf.so")

_registered: str | None = None


def intel_runtime_library(prefix: str = sys.prefix) -> Path | None:
    """``libintelocl.so`` of the ``intel-opencl-rt`` wheel installed in this environment, if any."""
    path = Path(prefix) / "lib" / "libintelocl.so"
    return path if path.is_file() else None


def vendors_dir_for(prefix: str = sys.prefix) -> Path:
    """A directory of this environment's own, outside the (possibly read-only) environment."""
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    tag = hashlib.sha256(str(Path(prefix).resolve()).encode()).hexdigest()[:12]
    return cache / "sdfserver" / f"opencl-vendors-{tag}"


def _write_if_changed(path: Path, text: str) -> None:
    if path.is_file() and path.read_text() == text:
        return
    staging = path.with_name(f".{path.name}.{os.getpid()}")
    staging.write_text(text)
    staging.replace(path)  # atomic: another process starting now reads the old or the new file


def write_vendors_dir(directory: Path, intel_library: Path,
                      system_dir: Path = SYSTEM_VENDORS_DIR) -> list[str]:
    """Mirror ``system_dir``'s ``.icd`` files into ``directory`` and add Intel's; returns the names."""
    directory.mkdir(parents=True, exist_ok=True)
    wanted: dict[str, str] = {}
    if system_dir.is_dir():
        for icd in sorted(system_dir.glob("*.icd")):
            try:
                wanted[icd.name] = icd.read_text()
            except OSError as exc:
                log.warning("cannot read OpenCL vendor file %s: %s", icd, exc)
    wanted[INTEL_ICD_NAME] = f"{intel_library}\n"
    for name, text in wanted.items():
        _write_if_changed(directory / name, text)
    for stale in directory.glob("*.icd"):
        if stale.name not in wanted:
            stale.unlink(missing_ok=True)
    return sorted(wanted)


def register_cpu_runtimes() -> str | None:
    """Make Intel's CPU runtime visible to the ICD loader, once a process. Returns how it was
    registered (a vendors directory, or ``OCL_ICD_VENDORS`` as the user set it), or None when
    the runtime is not installed or cannot be loaded (then PoCL and any system driver remain)."""
    global _registered
    if _registered is not None:
        return _registered
    library = intel_runtime_library()
    if library is None:
        return None
    try:
        for name in INTEL_COMPILER_LIBRARIES:
            ctypes.CDLL(str(library.parent / name), mode=ctypes.RTLD_GLOBAL)
    except OSError as exc:
        log.warning("Intel's CPU OpenCL runtime is installed but cannot be loaded (%s); "
                    "reinstall with `pip install -e '.[cpu]'`", exc)
        return None
    # pyopencl keeps binaries of runtimes that cache no builds of their own, like Intel's, but a
    # program Intel's runtime creates from a binary has no kernel argument info, and without it
    # every launch sets its arguments the slow way (sdfserver/gpu/programs.py). pyopencl reads
    # this when it is imported, which sdfserver's modules do after this call.
    os.environ.setdefault("PYOPENCL_NO_CACHE", "1")
    if os.environ.get("OCL_ICD_VENDORS"):
        _registered = os.environ["OCL_ICD_VENDORS"]
        return _registered
    directory = vendors_dir_for()
    try:
        write_vendors_dir(directory, library)
    except OSError as exc:
        log.warning("cannot write the OpenCL vendors directory %s (%s); Intel's CPU runtime "
                    "stays unregistered", directory, exc)
        return None
    os.environ["OCL_ICD_VENDORS"] = str(directory)
    _registered = str(directory)
    return _registered
