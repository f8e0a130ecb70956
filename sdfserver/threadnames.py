"""The operating system's name of a thread (``/proc/<pid>/task/<tid>/comm``) set to its Python name,
so that ``top -H``, ``py-spy`` and ``tools/cpu_use.py`` tell the server's threads apart: without
it every thread of a process is called ``python3``."""

from __future__ import annotations

import threading

OS_NAME_BYTES = 15  # the kernel keeps 15 bytes of a thread's name
PREFIX = "sdfserver-"


def name_os_thread() -> None:
    """Name the calling thread after its Python name, less the ``sdfserver-`` prefix (a thread's
    first act, or a pool's ``initializer``). Where there is no /proc (not Linux), nothing."""
    name = threading.current_thread().name.removeprefix(PREFIX)
    try:
        with open("/proc/thread-self/comm", "w") as comm:
            comm.write(name.encode()[:OS_NAME_BYTES].decode(errors="ignore"))
    except OSError:
        pass
