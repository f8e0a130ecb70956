"""A world's own copies of the shared kernels, each keeping the arguments it was last given.

``ProgramCache.kernel`` hands every world the same kernel object, so each launch sets all of
its arguments again. A world's recompute launches the same passes over the same region step
after step (under a cap near the world's side, always the whole world), so most of those
settings repeat the last ones. And where the driver keeps no argument info (the Intel OpenCL
CPU runtime, for programs from pyopencl's binary cache), ``declare_scalar_args`` cannot declare
the by-value arguments and pyopencl sets each one through its generic path, ~5-10 us of host
time an ``int4`` or ``int`` against ~1 us through ``_set_arg_buf`` (the call pyopencl's own
generated launchers make for declared arguments): exact's three passes set 27 of them, ~150 us
a world a step, and a world's brush launch (``brushes.py``) 5 to 7 more. ``KernelCopies.enqueue`` sets only the arguments that differ from that copy's
last launch, by-value ones as their bytes. One per dense world (``WorldBuffers.kernels``), used
only on the engine thread; OpenCL takes a launch's arguments when it is enqueued, so changing
them afterwards is safe.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyopencl as cl


def _same(a: Any, b: Any) -> bool:
    """Whether argument ``a`` is the value ``b`` the copy has: by-value arguments (bytes, NumPy
    scalars) by value, buffers only when the same object (one may be released since)."""
    if a is b:
        return True
    return type(a) is type(b) and isinstance(a, (bytes, np.generic)) and bool(a == b)


class KernelCopies:
    def __init__(self) -> None:
        self._copies: dict[cl.Kernel, list] = {}  # shared kernel -> [its copy, the args it last had]

    def enqueue(self, queue: cl.CommandQueue, kernel: cl.Kernel, global_size: tuple, local_size: tuple | None,
                args: tuple) -> cl.Event:
        """Launch this world's copy of ``kernel`` with ``args``, setting only those that changed
        (none where ``args`` is the very tuple of its last launch: a prepared launch's)."""
        found = self._copies.get(kernel)
        if found is None:
            found = self._copies[kernel] = [cl.Kernel(kernel.program, kernel.function_name), None]
        copy, last = found
        if args is not last:
            for i, value in enumerate(args):
                if last is None or not _same(value, last[i]):
                    if type(value) is bytes:  # int4 and float4 (algorithms.base)
                        copy._set_arg_buf(i, value)
                    elif isinstance(value, np.generic):
                        copy._set_arg_buf(i, value.tobytes())
                    else:  # buffers
                        copy.set_arg(i, value)
            found[1] = args
        return cl.enqueue_nd_range_kernel(queue, copy, global_size, local_size)

    def __len__(self) -> int:
        return len(self._copies)
