"""Devices are proven before use; Intel's CPU runtime is registered with the ICD loader."""

from __future__ import annotations

import logging
import os
import subprocess
import sys

import pytest

from sdfserver.errors import NoOpenCLDevice
from sdfserver.gpu import device as devices
from sdfserver import cpu_runtimes as runtimes
from sdfserver.gpu.device import DeviceProof, choose_device, describe_devices, label, prove, usable_devices

BROKEN_KERNEL = "__kernel void sdf_proof(__global uint *out, uint k) { out[0] = no_such_name; }\n"


def test_a_working_device_passes_its_proof(gpu):
    assert prove(gpu.device) == DeviceProof(True)


def test_a_device_that_cannot_build_fails_its_proof_with_the_build_error(gpu, monkeypatch):
    monkeypatch.setattr(devices, "_PROOF_SOURCE", BROKEN_KERNEL)
    proof = devices._run_proof(gpu.device)
    assert not proof.usable
    assert "no_such_name" in proof.reason or "BUILD_PROGRAM_FAILURE" in proof.reason


def test_a_failing_device_is_skipped_with_one_warning_and_listed_with_its_reason(gpu, monkeypatch, caplog):
    failing = gpu.device
    monkeypatch.setattr(devices, "_proofs", {devices._key(failing): DeviceProof(False, "unknown target CPU 'generic'")})
    monkeypatch.setattr(devices, "_warned", set())
    with caplog.at_level(logging.WARNING, logger="sdfserver.gpu.device"):
        usable_devices()
        usable_devices()
    assert failing not in usable_devices()
    warnings = [r.getMessage() for r in caplog.records if label(failing) in r.getMessage()]
    assert len(warnings) == 1 and "unknown target CPU 'generic'" in warnings[0]
    listing = [line for line in describe_devices() if label(failing) in line]
    assert listing and all("NOT usable: unknown target CPU 'generic'" in line for line in listing)
    with pytest.raises(NoOpenCLDevice, match="cannot be used: unknown target CPU"):
        choose_device(str(describe_devices().index(listing[0])))


def test_no_working_device_names_each_reason_and_the_fixes(gpu, monkeypatch):
    monkeypatch.setattr(devices, "prove", lambda device: DeviceProof(False, "it is broken"))
    monkeypatch.setattr(devices, "_warned", set())
    with pytest.raises(NoOpenCLDevice) as info:
        choose_device()
    message = str(info.value)
    assert "No OpenCL device works" in message and "it is broken" in message
    assert "pocl-opencl-icd" in message and "[cpu]" in message


def test_vendors_dir_mirrors_the_system_files_and_adds_intel(tmp_path):
    system = tmp_path / "etc"
    system.mkdir()
    (system / "nvidia.icd").write_text("libnvidia-opencl.so.1\n")
    mirror = tmp_path / "mirror"
    mirror.mkdir()
    (mirror / "gone.icd").write_text("/old/libgone.so\n")
    names = runtimes.write_vendors_dir(mirror, tmp_path / "lib" / "libintelocl.so", system)
    assert names == ["intel-cpu.icd", "nvidia.icd"]
    assert sorted(p.name for p in mirror.glob("*.icd")) == names
    assert (mirror / "nvidia.icd").read_text() == "libnvidia-opencl.so.1\n"
    assert (mirror / "intel-cpu.icd").read_text() == f"{tmp_path / 'lib' / 'libintelocl.so'}\n"


def _fresh_process(env: dict[str, str]) -> str:
    code = ("import os, sdfserver.gpu as g; "
            "print(os.environ.get('OCL_ICD_VENDORS')); print(g.describe_devices())")
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          check=True, timeout=120).stdout


@pytest.mark.skipif(runtimes.intel_runtime_library() is None, reason="intel-opencl-rt is not installed here")
def test_intel_runtime_is_registered_in_a_fresh_process(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "OCL_ICD_VENDORS"}
    env["XDG_CACHE_HOME"] = str(tmp_path)
    vendors, listing = _fresh_process(env).splitlines()
    assert vendors.startswith(str(tmp_path))
    assert "Intel(R) OpenCL" in listing


@pytest.mark.skipif(runtimes.intel_runtime_library() is None, reason="intel-opencl-rt is not installed here")
def test_a_users_own_vendors_setting_is_left_as_it_is(tmp_path):
    env = {**os.environ, "OCL_ICD_VENDORS": str(tmp_path), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    vendors, listing = _fresh_process(env).splitlines()
    assert vendors == str(tmp_path)
    assert "Intel(R) OpenCL" not in listing
    assert not (tmp_path / "cache" / "sdfserver").exists()


@pytest.mark.skipif(runtimes.intel_runtime_library() is None, reason="intel-opencl-rt is not installed here")
def test_kernels_keep_their_argument_info_on_intels_runtime_across_processes(tmp_path):
    """A program Intel's runtime loads from pyopencl's binary cache has no argument info; pyopencl
    must build from source there even when a module that imports pyopencl is imported first.
    The second process would find the first one's binaries if caching were on."""
    code = ("import sdfserver.algorithms.base\n"  # imports pyopencl before sdfserver.gpu
            "from sdfserver.gpu import GpuContext\n"
            "from sdfserver.gpu.programs import scalar_arg_dtypes\n"
            "gpu = GpuContext.create('Intel')\n"
            "print(scalar_arg_dtypes(gpu.programs.kernel('edits.cl', 'fill_sphere')) is not None)\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OCL_ICD_VENDORS", "PYOPENCL_NO_CACHE")}
    env["XDG_CACHE_HOME"] = str(tmp_path)
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                             check=True, timeout=120).stdout
        assert out.strip() == "True"
