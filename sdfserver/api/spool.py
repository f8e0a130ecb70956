"""An import's body, written to a temporary file as it arrives instead of held in memory.

A real world file is large (a Minecraft region as ``.npy`` is 100 MB), and holding the body whole
while the voxels are decoded from it would take twice that in the API process, for every import
in flight. The body goes to an unnamed temporary file in the data directory's ``imports/`` (the
system's temporary directory when worlds are not kept on disk), which the system removes when it
is closed or the process ends. The parsers read it through a read-only memory map, whose pages
are the kernel's cache rather than the process's heap; a ``.npy`` file is read straight into its
array.
"""

from __future__ import annotations

import asyncio
import mmap
import tempfile
from pathlib import Path
from typing import Any, BinaryIO

from fastapi import Request
from starlette.requests import ClientDisconnect

from sdfserver.api.bodies import header
from sdfserver.errors import BodyTooLarge
from sdfserver.storage.uploads import SNIFF_BYTES, upload_format

WRITE_BYTES = 1 << 20  # body messages gathered before each write, which runs off the event loop
IMPORTS_DIR = "imports"


class Spooled:
    """A body on disk: its ``format`` (told by its first bytes), ``size`` and ``file``."""

    def __init__(self, file: BinaryIO, size: int, fmt: str):
        self.file, self.size, self.format = file, size, fmt
        self._map: mmap.mmap | None = None

    def view(self) -> mmap.mmap:
        """The whole body, read-only (slicing it copies only the slice)."""
        if self._map is None:
            self._map = mmap.mmap(self.file.fileno(), 0, access=mmap.ACCESS_READ)
        return self._map

    def stream(self) -> BinaryIO:
        """The file, from its start."""
        self.file.seek(0)
        return self.file

    def close(self) -> None:
        if self._map is not None:
            try:
                self._map.close()
            except BufferError:  # a view of it outlives the import (a failed parse's traceback)
                pass  # the mapping goes with that view; the file's descriptor is closed below
        self.file.close()


def spool_directory(settings: Any) -> str | None:
    """Where import bodies are spooled: ``data_dir/imports`` when worlds are kept on disk (the
    system's temporary directory may be held in memory), else the system's (None)."""
    if not settings.persist:
        return None
    directory = Path(settings.data_dir) / IMPORTS_DIR
    directory.mkdir(parents=True, exist_ok=True)
    return str(directory)


async def spool_upload(request: Request, limit_bytes: int, given: str | None, directory: str | None) -> Spooled:
    """The request's body in a temporary file. A declared ``Content-Length`` past ``limit_bytes``
    is refused before the body is read, a body that grows past it as soon as it does (413); the
    format is told from the first bytes (422 for none this server imports, or one other than
    ``given``) before anything is written."""
    length = header(request, b"content-length")
    declared = int(length) if length is not None and length.isdigit() else 0
    if declared > limit_bytes:
        raise BodyTooLarge(f"an import of {declared} bytes exceeds the limit of {limit_bytes} bytes "
                           f"(max_import_bytes)")
    file = tempfile.TemporaryFile(dir=directory, prefix="import-")
    try:
        size, head, fmt = 0, b"", None
        pending: list[bytes] = []
        held, more = 0, True
        while more:
            message = await request.receive()
            if message["type"] == "http.disconnect":
                raise ClientDisconnect()
            body = message.get("body", b"")
            more = message.get("more_body", False)
            size += len(body)
            if size > limit_bytes:
                raise BodyTooLarge(f"an import of more than {limit_bytes} bytes exceeds the limit (max_import_bytes)")
            if fmt is None:
                head += body[:SNIFF_BYTES - len(head)]
                if len(head) >= SNIFF_BYTES or not more:
                    fmt = upload_format(head, given)
            pending.append(body)
            held += len(body)
            if held >= WRITE_BYTES or not more:
                await asyncio.to_thread(_write, file, pending)
                pending, held = [], 0
        return Spooled(file, size, fmt)
    except BaseException:
        file.close()
        raise


def _write(file: BinaryIO, parts: list[bytes]) -> None:
    file.writelines(parts)
    file.flush()


__all__ = ["Spooled", "spool_directory", "spool_upload"]
