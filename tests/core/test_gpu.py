"""GPU plumbing: device choice, the program loader, the memory budget."""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest

from sdfserver.algorithms.base import WORK_PLANE_PAD
from sdfserver.algorithms.exact import Exact
from sdfserver.errors import DeviceMemoryExceeded, InvalidInput, KernelBuildError, NoOpenCLDevice
from sdfserver.gpu import GpuContext, choose_device, describe_devices
from sdfserver.gpu import programs
from sdfserver.gpu.uploads import UploadRing
from sdfserver.world import World, WorldConfig


def test_no_platform_says_how_to_fix(monkeypatch):
    def no_platforms():
        raise cl.LogicError("clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR")

    monkeypatch.setattr(cl, "get_platforms", no_platforms)
    with pytest.raises(NoOpenCLDevice, match=r"pip install -e '\.\[cpu\]'"):
        choose_device()


def test_device_spec_by_index_and_name():
    listing = describe_devices()
    assert listing and listing[0].startswith("0: ")
    first = choose_device("0")
    assert choose_device(first.name.strip()[:6]).name == first.name
    with pytest.raises(NoOpenCLDevice, match="No OpenCL device matches"):
        choose_device("no-such-device-anywhere")
    with pytest.raises(NoOpenCLDevice, match="out of range"):
        choose_device("99")


def test_failed_build_carries_file_options_and_log(gpu, tmp_path, monkeypatch):
    (tmp_path / "broken.cl").write_text("__kernel void k(__global int *a) { a[0] = undefined_name; }\n")
    monkeypatch.setattr(programs, "KERNEL_DIR", tmp_path)
    with pytest.raises(KernelBuildError) as info:
        gpu.programs.get("broken.cl", FLAVOUR=3)
    assert info.value.path.endswith("broken.cl")
    assert "-DFLAVOUR=3" in info.value.options
    assert "undefined_name" in info.value.log


def test_programs_are_memoized_per_options(gpu):
    a = gpu.programs.get("exact.cl", AXIS=1, SEG=4, LOCAL_X=32, LOCAL_Y=2)
    assert gpu.programs.get("exact.cl", SEG=4, LOCAL_Y=2, AXIS=1, LOCAL_X=32) is a
    assert gpu.programs.get("exact.cl", AXIS=2, SEG=4, LOCAL_X=32, LOCAL_Y=2) is not a


def test_every_kernel_declares_its_scalar_argument_types(gpu):
    """Without declared types pyopencl probes each argument on every launch (~50 us a kernel on
    the H200 host): every kernel in kernels/ must have argument info the loader understands."""
    int4 = cl.cltypes.int4
    expected = {"fill_sphere": [None, int4, int4, int4, int4, cl.cltypes.float4, np.float32, np.uint32],
                "set_voxels": [None, int4, int4, None, np.int32]}
    kernels = [Exact().launch_shape(gpu, axis, 64, 64, 64, 64)[0] for axis in range(3)]  # needs defines
    kernels += gpu.programs.get("jfa.cl", JFA_STEP=1).all_kernels()  # compiled for each pass's step
    for path in sorted(programs.KERNEL_DIR.glob("*.cl")):
        if path.name not in ("exact.cl", "jfa.cl"):
            kernels += gpu.programs.get(path.name).all_kernels()
    found = {}
    for kernel in kernels:
        dtypes = programs.scalar_arg_dtypes(kernel)
        assert dtypes is not None and len(dtypes) == kernel.num_args, kernel.function_name
        found[kernel.function_name] = dtypes
    assert {"pass_x", "pass_yz", "render", "query_points", "init_work"} <= set(found)
    for name, dtypes in expected.items():
        assert found[name] == expected[name], name


def test_world_over_budget_fails_before_allocating(gpu):
    small = GpuContext(gpu.device, memory_budget_bytes=1 << 20)
    with pytest.raises(DeviceMemoryExceeded, match="MiB"):
        World(small, WorldConfig((128, 128, 128), 16))
    assert small.allocated_bytes == 0
    world = World(small, WorldConfig((32, 32, 32), 16))  # 160 KiB fits
    assert small.allocated_bytes == 5 * 32 ** 3 + 32 * WORK_PLANE_PAD  # exact's padded work planes
    world.release()
    assert small.allocated_bytes == 0


@pytest.mark.parametrize("config,message", [
    (dict(size=(30, 32, 32), chunk_size=16), "multiples"),
    (dict(size=(32, 32, 32), chunk_size=12), "chunk_size"),
    (dict(size=(32, 32, 32), chunk_size=16, max_distance=0), "max_distance"),
    (dict(size=(32, 32, 32), chunk_size=16, max_distance=256), "max_distance"),
    (dict(size=(32, 32, 32), chunk_size=16, algorithm="magic"), "unknown algorithm"),
    (dict(size=(32, 32), chunk_size=16), "three integers"),
    (dict(size=(4096, 8, 8), chunk_size=8), "at most"),
])
def test_bad_world_config(gpu, config, message):
    before = gpu.allocated_bytes
    with pytest.raises(InvalidInput, match=message):
        World(gpu, WorldConfig(**config))
    assert gpu.allocated_bytes == before


def test_staged_uploads_keep_every_array_intact_while_slots_are_reused(gpu, rng):
    """Many more uploads than slots, none waited for: each array's device copy, read back right
    after it on the in-order queue, is that array; oversized ones get a buffer of their own."""
    ring = UploadRing(gpu.context, gpu.queue, slot_bytes=4096, slots=3)
    arrays = [rng.integers(0, 1 << 30, size=int(rng.integers(1, 1025)), dtype=np.int32) for _ in range(40)]
    arrays[7] = rng.integers(0, 1 << 30, size=5000, dtype=np.int32)  # over the slot size
    copies = [np.zeros_like(a) for a in arrays]
    for array, copy in zip(arrays, copies):
        with ring.staged(array) as buffer:
            cl.enqueue_copy(gpu.queue, copy, buffer, is_blocking=False)
    gpu.queue.finish()
    for i, (array, copy) in enumerate(zip(arrays, copies)):
        assert np.array_equal(copy, array), f"upload {i}"
    assert ring.fallbacks >= 1  # the oversized one
