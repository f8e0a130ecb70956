"""Host cost of the OpenCL calls an engine step makes, from Python on this device: a launch through
pyopencl (``enqueue_nd_range_kernel``, and a kernel object's call, which sets its arguments too),
the same launch through ctypes with and without an event, a small non-blocking write, setting one
argument, reading an event's profile. For each: the wall and thread CPU time a call, the mean of
``--calls`` (docs/benchmarks.md, "Where the engine process's GIL goes").

    PYTHONPATH=$PWD python3 tools/opencl_call_cost.py --device nvidia [--calls 3000]
"""

from __future__ import annotations

import argparse
import ctypes
import glob
import os
import time

import numpy as np
import pyopencl as cl

from sdfserver.gpu import GpuContext

SOURCE = "__kernel void k(__global int *a, int n) { int i = get_global_id(0); if (i < n) a[i] += i; }"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default=None)
    parser.add_argument("--calls", type=int, default=3000)
    args = parser.parse_args()
    gpu = GpuContext.create(args.device)
    queue, context = gpu.queue, gpu.context
    kernel = cl.Kernel(cl.Program(context, SOURCE).build(), "k")
    data = cl.Buffer(context, cl.mem_flags.READ_WRITE, 1 << 20)
    small = cl.Buffer(context, cl.mem_flags.READ_ONLY, 16 << 10)
    kernel.set_args(data, np.int32(1024))
    # pyopencl's own ICD loader, which hands the calls to the same driver
    lib = ctypes.CDLL(glob.glob(os.path.join(os.path.dirname(cl.__file__), ".libs", "libOpenCL*"))[0])
    lib.clEnqueueNDRangeKernel.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint, ctypes.c_void_p,
                                           ctypes.POINTER(ctypes.c_size_t), ctypes.POINTER(ctypes.c_size_t),
                                           ctypes.c_uint, ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p)]
    lib.clReleaseEvent.argtypes = [ctypes.c_void_p]
    global_size, local_size = (ctypes.c_size_t * 1)(1024), (ctypes.c_size_t * 1)(64)
    queue_ptr, kernel_ptr, event = ctypes.c_void_p(queue.int_ptr), ctypes.c_void_p(kernel.int_ptr), ctypes.c_void_p()
    records = np.zeros((8, 16), np.int32)  # a step's brush records: 512 bytes
    done = cl.enqueue_nd_range_kernel(queue, kernel, (1024,), (64,))
    done.wait()

    def ctypes_with_event() -> None:
        lib.clEnqueueNDRangeKernel(queue_ptr, kernel_ptr, 1, None, global_size, local_size, 0, None,
                                   ctypes.byref(event))
        lib.clReleaseEvent(event)

    calls = {
        "pyopencl enqueue_nd_range_kernel": (lambda: cl.enqueue_nd_range_kernel(queue, kernel, (1024,), (64,)), 50),
        "pyopencl kernel(...) (sets 2 arguments)": (lambda: kernel(queue, (1024,), (64,), data, np.int32(1024)), 50),
        "ctypes clEnqueueNDRangeKernel, event": (ctypes_with_event, 50),
        "ctypes clEnqueueNDRangeKernel, no event": (
            lambda: lib.clEnqueueNDRangeKernel(queue_ptr, kernel_ptr, 1, None, global_size, local_size, 0, None, None), 50),
        "pyopencl enqueue_copy, 512 B, non-blocking": (lambda: cl.enqueue_copy(queue, small, records, is_blocking=False), 50),
        "Kernel._set_arg_buf, one int": (lambda: kernel._set_arg_buf(1, np.int32(1024).tobytes()), 0),
        "Event.profile end - start": (lambda: done.profile.end - done.profile.start, 0),
    }
    def timed(call, finish_every: int) -> tuple[float, float]:
        wall, cpu = time.perf_counter(), time.thread_time()
        for i in range(args.calls):
            call()
            if finish_every and i % finish_every == finish_every - 1:
                queue.finish()
        wall, cpu = time.perf_counter() - wall, time.thread_time() - cpu
        queue.finish()
        return wall / args.calls * 1e6, cpu / args.calls * 1e6

    print(gpu.device_name)
    print(f"{'call':44s} {'wall us':>8s} {'CPU us':>8s}")
    for name, (call, finish_every) in calls.items():
        for _ in range(100):
            call()
        queue.finish()
        wall, cpu = timed(call, finish_every)
        print(f"{name:44s} {wall:8.2f} {cpu:8.2f}")


if __name__ == "__main__":
    main()
