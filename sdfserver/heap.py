"""Megabyte buffers from memory the process already has, not from fresh pages.

A large query or read passes through several buffers of a megabyte or more in each process (a
request body, a message frame, the decoded arrays, the encoded answer). glibc's malloc serves
each from a new ``mmap`` at first, then raises its mmap threshold to the size of the largest one
freed but returns the top of its heap to the system once more than twice that is free. Either
way a buffer often lands on pages the process does not hold, and every 4 KiB page of it costs a
page fault as it is first written: for one 100,000-point query, more time than copying the bytes
(``tools/query_timeline.py`` shows it hop by hop). ``keep_freed_memory`` makes buffers up to
``MMAP_THRESHOLD_BYTES`` come from the heap and keeps up to ``TRIM_THRESHOLD_BYTES`` of freed
heap for the next one. API processes and engine processes call it after their start-up.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameters (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 << 20  # glibc's largest (HEAP_MAX_SIZE / 2 on 64-bit)
TRIM_THRESHOLD_BYTES = 32 << 20


def keep_freed_memory() -> bool:
    """Set glibc's thresholds for this process; False where the C library is not glibc."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
