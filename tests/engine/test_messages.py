"""The engine's typed requests without HTTP or sockets: messages through msgspec and back, one
handler per type, replies in order, a bad batch refused alone and validated once, access
checked by the engine."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from sdfserver.engine import Engine
from sdfserver.engine import messages as msg
from sdfserver.engine.access import Doorkeeper, RateLimiter
from sdfserver.engine.service import EngineService, SubscriptionNews
from sdfserver.errors import InvalidEdit, NotFound, RateLimited
from sdfserver.storage.codec import encode_batch

CONFIG = {"size": [16, 16, 16], "chunk_size": 8, "max_distance": 8, "algorithm": "exact", "focus": None,
          "lod_algorithm": "jfa", "borders": "exact"}


class Outbox:
    def __init__(self):
        self.items: list = []
        self.arrived = threading.Condition()

    def send(self, client: bytes, item) -> None:
        if isinstance(item, SubscriptionNews):
            item = self.service.update_for(client, item)
            if item is None:
                return
        # every output crosses the codec, as between processes
        item = msg.OUTPUTS_DECODER.decode(msg.REQUEST_ENCODER.encode(msg.Outputs([item]))).items[0]
        with self.arrived:
            self.items.append((client, item))
            self.arrived.notify_all()

    def reply(self, request_id: int, timeout_s: float = 30.0) -> msg.Reply:
        with self.arrived:
            assert self.arrived.wait_for(lambda: any(isinstance(i, msg.Reply) and i.id == request_id
                                                     for _, i in self.items), timeout_s), request_id
            return next(i for _, i in self.items if isinstance(i, msg.Reply) and i.id == request_id)


@pytest.fixture
def served(gpu):
    engine = Engine(gpu)
    engine.start(warm_up=False)
    outbox = Outbox()
    doorkeeper = Doorkeeper(RateLimiter(0.0), engine.owner_of, lambda: list(engine.owners.values()))
    service = EngineService(engine, doorkeeper, outbox.send)
    outbox.service = service

    def ask(request) -> msg.Reply:
        service.handle(b"api-1", msg.REQUEST_DECODER.decode(msg.REQUEST_ENCODER.encode(request)))
        return outbox.reply(request.id)

    yield service, ask, outbox
    engine.stop()


def test_requests_round_trip_through_msgspec_and_answer_in_order(served):
    service, ask, _ = served
    world = ask(msg.CreateWorld(1, CONFIG)).result
    assert world["version"] == 0 and world["size"] == [16, 16, 16]
    batch = [{"op": "voxels", "voxels": np.array([[3, 4, 5, 9], [3, 4, 5, 7]], dtype=np.uint16)},
             {"op": "box", "min": [8, 8, 8], "max": [10, 10, 10], "colour": 2}]
    assert ask(msg.ApplyEdits(2, world["id"], encode_batch(batch))).result == 1
    read = msg.decode_result(ask(msg.Read(3, world["id"], "voxels", (0, 0, 0), (16, 16, 16), 1)).result,
                             msg.ReadResult)
    voxels = read.array.numpy()
    assert read.version == 1 and voxels[5, 4, 3] == 7  # the later duplicate wins
    assert voxels[8:10, 8:10, 8:10].tolist() == np.full((2, 2, 2), 2).tolist()
    points = msg.Array.of(np.array([[3.5, 4.5, 5.5], [0.0, 0.0, 0.0]]))  # a voxel's centre, a corner
    query = msg.decode_result(ask(msg.Query(4, world["id"], points, 1)).result, msg.QueryResult)
    distances = query.arrays["distances"].numpy()
    assert distances.tolist()[0] == 0 and distances[1] > 0 and query.arrays["colours"].numpy()[0] == 7
    rays = msg.Array.of(np.array([[0.5, 4.5, 5.5, 1.0, 0.0, 0.0, 16.0]]))
    hit = msg.decode_result(ask(msg.Query(5, world["id"], rays, 1, None, "rays")).result, msg.QueryResult)
    assert hit.arrays["voxels"].numpy().tolist() == [[3, 4, 5]] and hit.arrays["distances"].numpy()[0] == 2.5


def test_a_bad_batch_fails_alone_and_changes_nothing(served):
    service, ask, _ = served
    world = ask(msg.CreateWorld(1, CONFIG)).result["id"]
    bad = ask(msg.ApplyEdits(2, world, encode_batch([{"op": "sphere", "center": [1, 1], "radius": 2}])))
    assert bad.failure is not None and bad.failure.kind == InvalidEdit.__name__
    with pytest.raises(InvalidEdit):
        msg.raise_failure(bad.failure)
    assert ask(msg.Describe(3, world)).result["version"] == 0
    missing = ask(msg.ApplyEdits(4, "no-such-world", encode_batch([])))
    assert missing.failure.kind == NotFound.__name__


def test_access_is_checked_by_the_engine(served):
    service, ask, _ = served
    alice, bob = msg.Access("alice", False, "1.2.3.4"), msg.Access("bob", False, "1.2.3.5")
    world = ask(msg.CreateWorld(1, CONFIG, alice)).result
    assert world["owner"] == "alice"
    assert ask(msg.Describe(2, world["id"], alice)).failure is None
    assert ask(msg.Describe(3, world["id"], bob)).failure.kind == NotFound.__name__
    assert ask(msg.Describe(4, None, bob)).result == []
    assert ask(msg.CreateWorld(5, CONFIG, alice, max_owned=1)).failure.message.endswith("its limit")
    service.doorkeeper.limiter = RateLimiter(rate_per_s=0.001, burst=1)
    assert ask(msg.Admit(6, alice)).failure is None
    assert ask(msg.Admit(7, alice)).failure.kind == RateLimited.__name__


def test_a_subscription_gets_the_current_chunks_then_the_changed_ones(served):
    service, ask, outbox = served
    world = ask(msg.CreateWorld(1, CONFIG)).result["id"]
    assert ask(msg.Subscribe(2, world, 7, (0, 0, 0), (8, 8, 8), "distance")).failure is None
    ask(msg.ApplyEdits(3, world, encode_batch([{"op": "box", "min": [1, 1, 1], "max": [2, 2, 2], "colour": 1}])))
    ask(msg.Read(4, world, "distance", None, None, 1))
    updates = [i for _, i in outbox.items if isinstance(i, msg.ChunkUpdate)]
    assert len(updates) == 1 and updates[0].subscription == 7  # no more until the first is taken
    service.handle(b"api-1", msg.Taken(0, 7))  # answers nothing; sends what merged meanwhile
    with outbox.arrived:
        outbox.arrived.wait_for(lambda: sum(isinstance(i, msg.ChunkUpdate) for _, i in outbox.items) == 2, 10)
    updates = [i for _, i in outbox.items if isinstance(i, msg.ChunkUpdate)]
    assert len(updates) == 2 and updates[-1].version == 1 and updates[-1].chunks[0][0] == (0, 0, 0)
    service.forget(b"api-1")
    assert not service.subscriptions


def test_a_subscription_told_it_ended_while_its_update_is_unsent_hears_it_when_taken(served):
    service, ask, outbox = served
    world = ask(msg.CreateWorld(1, CONFIG)).result["id"]
    assert ask(msg.Subscribe(2, world, 7, (0, 0, 0), (8, 8, 8), "distance")).failure is None
    service.engine.subscriptions.drop_world(world, "moved to engine 1")  # its first update not yet taken
    assert not [i for _, i in outbox.items if isinstance(i, msg.ChunkUpdate) and i.ended]
    service.handle(b"api-1", msg.Taken(0, 7))
    with outbox.arrived:
        assert outbox.arrived.wait_for(
            lambda: any(isinstance(i, msg.ChunkUpdate) and i.ended for _, i in outbox.items), 10)


def test_an_answer_that_cannot_be_encoded_is_answered_with_its_failure():
    import numpy as np

    from sdfserver.engine.frames import HEADER
    from sdfserver.engine.transport import framed

    items = [msg.Reply(1, {"n": np.int64(3)}), msg.Reply(2, 5)]  # a numpy integer: msgspec refuses it
    data, = framed(items, 1 << 20)
    replies = msg.OUTPUTS_DECODER.decode(bytes(data[HEADER:])).items
    assert [r.id for r in replies] == [1, 2] and replies[1].result == 5
    assert replies[0].failure is not None and replies[0].failure.kind == "SdfServerError"
