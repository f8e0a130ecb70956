"""The write-coalescing transport under uvicorn's protocol: order, merging, large writes, close."""

from __future__ import annotations

import asyncio

from sdfserver.api.coalesce import COALESCE_LIMIT_BYTES, CoalescingTransport


class RecordingTransport:
    def __init__(self) -> None:
        self.writes: list[bytes] = []
        self.closed = False

    def write(self, data: bytes) -> None:
        assert not self.closed, "write after close"
        self.writes.append(bytes(data))

    def is_closing(self) -> bool:
        return self.closed

    def close(self) -> None:
        self.closed = True

    def get_write_buffer_size(self) -> int:
        return 0

    def get_extra_info(self, name: str, default=None):
        return {"peername": ("127.0.0.1", 5)}.get(name, default)


def run(body) -> RecordingTransport:
    inner = RecordingTransport()

    async def main() -> None:
        await body(CoalescingTransport(inner, asyncio.get_running_loop()))

    asyncio.run(main())
    return inner


def test_small_writes_of_one_iteration_go_out_as_one() -> None:
    async def body(t: CoalescingTransport) -> None:
        t.write(b"HTTP/1.1 200 OK\r\ncontent-length: 2\r\n\r\n")
        t.write(b"ok")
        assert t.inner.writes == []  # not yet: the iteration is not over
        assert t.get_write_buffer_size() == 40
        await asyncio.sleep(0)
        t.write(b"next")
        await asyncio.sleep(0)

    inner = run(body)
    assert inner.writes == [b"HTTP/1.1 200 OK\r\ncontent-length: 2\r\n\r\nok", b"next"]


def test_a_large_write_goes_out_at_once_after_what_was_pending() -> None:
    large = b"x" * COALESCE_LIMIT_BYTES

    async def body(t: CoalescingTransport) -> None:
        t.write(b"head")
        t.write(large)
        assert t.inner.writes == [b"head", large]
        await asyncio.sleep(0)

    assert run(body).writes == [b"head", large]


def test_close_sends_what_is_pending_first_and_other_calls_reach_the_socket() -> None:
    async def body(t: CoalescingTransport) -> None:
        t.write(b"bye")
        assert t.get_extra_info("peername") == ("127.0.0.1", 5)
        t.close()
        assert t.is_closing()
        await asyncio.sleep(0)  # the scheduled flush finds nothing left

    inner = run(body)
    assert inner.writes == [b"bye"] and inner.closed
