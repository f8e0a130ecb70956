"""When ``EngineClient`` writes its requests: a request alone in flight at once, requests sent
while others await their answers together at the end of the event loop's turn."""

from __future__ import annotations

import asyncio

from sdfserver.api.engine_client import EngineClient
from sdfserver.engine import frames
from sdfserver.engine import messages as msg


class Recorder:
    """The requests connection: what was written, write by write."""

    def __init__(self) -> None:
        self.writes: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.writes.append(bytes(data))


def sent_ids(data: bytes) -> list[int]:
    return [msg.REQUEST_DECODER.decode(payload).id for payload in frames.FrameReader().feed(data)]


def test_a_lone_request_leaves_at_once_and_requests_in_flight_together_share_a_write():
    async def scenario() -> None:
        client = EngineClient("unix:/nowhere-in", "unix:/nowhere-out")
        client._loop = asyncio.get_running_loop()
        client._requests = requests = Recorder()
        first = asyncio.ensure_future(client.call(msg.Status(client.next_id())))
        await asyncio.sleep(0)  # the call has run, its turn has not ended
        assert [sent_ids(w) for w in requests.writes] == [[1]]
        more = [asyncio.ensure_future(client.call(msg.Status(client.next_id()))) for _ in range(3)]
        for _ in range(3):
            await asyncio.sleep(0)
        assert [sent_ids(w) for w in requests.writes] == [[1], [2, 3, 4]]
        client._take(msg.Outputs([msg.Reply(i, i * 10) for i in (1, 2, 3, 4)]))
        assert await asyncio.gather(first, *more) == [10, 20, 30, 40]

    asyncio.run(scenario())
