"""An engine's TCP links as a hostile peer meets them: an engine embedded in this process
(``serve_engine``, as a cluster's engine actor runs it, on the CPU device) listening on
loopback TCP with a credential, and raw sockets that do not hold it. Each peer that does not
prove itself is closed before anything it sent is decoded, counted in the engine's metrics,
and the engine goes on serving the API processes that did."""

from __future__ import annotations

import asyncio
import queue
import socket
import threading
import time

import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from sdfserver.api.engine_client import EngineClient
from sdfserver.cluster.engine_actor import free_ports
from sdfserver.engine import frames, links
from sdfserver.engine import messages as msg
from sdfserver.engine.proc import EngineAddress, serve_engine
from sdfserver.engine.worlds import world_config_dict
from sdfserver.errors import NotFound
from sdfserver.settings import Settings
from sdfserver.storage.codec import encode_batch
from sdfserver.world import WorldConfig

ALICE = msg.Access("alice", False, "10.0.0.1")
FORGED_ADMIN = msg.Access(None, True, "10.6.6.6")


class EmbeddedEngine:
    """``serve_engine`` on a thread, as the engine actor runs it; ``send`` is its launcher pipe."""

    def __init__(self, settings: Settings, address: EngineAddress):
        self.settings, self.address = settings, address
        self.limits = links.LinkLimits.of(settings)
        self.said: queue.Queue = queue.Queue()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=serve_engine, args=(settings, address, 1, self, self.stop),
                                       name="test-embedded-engine", daemon=True)

    def send(self, item: tuple[str, str]) -> None:
        self.said.put(item)

    def ask(self, *requests: msg.Request, credential: bytes | None = None) -> list:
        """Each request's result (or the exception it raised), from a client holding the credential."""
        async def main():
            client = EngineClient(self.address.input, self.address.output,
                                  self.address.credential if credential is None else credential, self.limits)
            await client.start()
            try:
                return await asyncio.gather(*(client.call(r) for r in requests), return_exceptions=True)
            finally:
                await client.stop()

        return asyncio.run(main())

    def refused(self, reason: str) -> float:
        """sdfserver_engine_links_refused_total{reason} as /metrics shows it."""
        text, = self.ask(msg.MetricsText(1))
        for family in text_string_to_metric_families(text):
            for sample in family.samples:
                if sample.name == "sdfserver_engine_links_refused_total" and sample.labels["reason"] == reason:
                    return sample.value
        return 0.0


@pytest.fixture(scope="module")
def engine(gpu):
    ports = free_ports(2, "127.0.0.1")
    address = EngineAddress(0, "", f"tcp://127.0.0.1:{ports[0]}", f"tcp://127.0.0.1:{ports[1]}",
                            links.new_credential())
    embedded = EmbeddedEngine(Settings(persist=False, warm_up=False, memory_budget_bytes=64 << 20), address)
    embedded.thread.start()
    kind, said = embedded.said.get(timeout=120)
    assert kind == "ready", said
    yield embedded
    embedded.stop.set()
    embedded.thread.join(timeout=30)


def alices_world(engine: EmbeddedEngine) -> str:
    config = world_config_dict(WorldConfig(size=(16, 16, 16), chunk_size=8, max_distance=5).validated())
    described, = engine.ask(msg.CreateWorld(1, config, ALICE))
    return described["id"]


def connect(address: str) -> socket.socket:
    _, target = frames.family_and_target(address)
    return socket.create_connection(target, timeout=5)


def closed_within(sock: socket.socket, seconds: float) -> bool:
    """Whether the engine closes ``sock`` within ``seconds`` (what it sends first is read and dropped)."""
    deadline = time.monotonic() + seconds
    try:
        while time.monotonic() < deadline:
            sock.settimeout(max(0.01, deadline - time.monotonic()))
            if not sock.recv(1 << 16):
                return True
    except (TimeoutError, socket.timeout):
        return False
    except ConnectionResetError:
        return True
    return False


def read_frame(sock: socket.socket) -> bytes:
    reader = frames.FrameReader(links.HELLO_BYTES)
    while True:
        data = sock.recv(1 << 16)
        assert data, "the engine closed the connection"
        got = reader.feed(data)
        if got:
            return bytes(got[0])


def proven_peer(engine: EmbeddedEngine, role: bytes = links.REQUESTS) -> socket.socket:
    """A raw connection that has proven itself as an API process would."""
    sock = connect(engine.address.input if role == links.REQUESTS else engine.address.output)
    proof = links.ApiSide(engine.address.credential, role, b"api-raw-test")
    sock.sendall(proof.heard(read_frame(sock)))
    proof.heard(read_frame(sock))
    assert proof.proven
    return sock


def test_a_forged_admin_delete_from_a_peer_without_the_credential_changes_nothing(engine):
    world = alices_world(engine)
    before = engine.refused("credential")
    forged = msg.REQUEST_ENCODER.encode(msg.DeleteWorld(7, world, FORGED_ADMIN))
    with connect(engine.address.input) as forger:
        forger.sendall(frames.frame(b"api-forger") + frames.frame(forged))
        closed = [closed_within(forger, 5)]
    with connect(engine.address.input) as guesser:  # a well-formed proof made without the credential
        challenge = read_frame(guesser)
        guesser.sendall(links.ApiSide(links.new_credential(), links.REQUESTS, b"api-forger").heard(challenge)
                        + frames.frame(forged))
        closed.append(closed_within(guesser, 5))
    described, = engine.ask(msg.Describe(2, world, ALICE))
    assert not isinstance(described, Exception), f"the forged delete was applied: {described!r}"
    assert described["id"] == world and described["owner"] == "alice"
    assert closed == [True, True], "the engine kept a connection that proved nothing"
    assert engine.refused("credential") == before + 2


def test_a_client_with_a_wrong_credential_is_not_welcomed_and_the_engine_still_serves(engine):
    before = engine.refused("credential")

    async def main():
        client = EngineClient(engine.address.input, engine.address.output, links.new_credential(), engine.limits)
        client._loop = asyncio.get_running_loop()
        with pytest.raises(ConnectionError):
            await client._open()

    asyncio.run(main())
    assert engine.refused("credential") >= before + 1
    status, = engine.ask(msg.Status(1))
    assert msg.decode_result(status, msg.EngineStatus).ready


@pytest.mark.parametrize("proven", [False, True], ids=["before its proof", "after its proof"])
def test_a_frame_header_announcing_4_gb_closes_the_connection_and_the_engine_still_serves(engine, proven):
    before = engine.refused("too_large")
    peer = proven_peer(engine) if proven else connect(engine.address.input)
    with peer:
        peer.sendall((2**32 - 1).to_bytes(frames.HEADER, "little") + b"x" * 1000)
        assert closed_within(peer, 5), "the engine waits for a 4 GB frame"
    assert engine.refused("too_large") == before + 1
    world = alices_world(engine)
    described, = engine.ask(msg.Describe(2, world, ALICE))
    assert described["id"] == world


def test_a_proven_peer_may_send_a_request_as_large_as_the_settings_allow(engine):
    """The limit after the proof is the settings' (an import of max_world_voxels voxels, or a
    sparse world's file of max_import_bytes as uploaded), not the proof's: an edit batch of 4 MB
    is read, applied and answered."""
    assert engine.limits.request_bytes >= max(engine.settings.max_world_voxels, engine.settings.max_import_bytes)
    world = alices_world(engine)
    rng = np.random.default_rng()
    voxels = np.column_stack([rng.integers(0, 16, (250_000, 3)), rng.integers(1, 256, 250_000)]).astype(np.int32)
    with proven_peer(engine) as requests, proven_peer(engine, links.ANSWERS) as answers:
        big = msg.ApplyEdits(5, world, encode_batch([{"op": "voxels", "voxels": voxels}]), ALICE)
        data = frames.frame(msg.REQUEST_ENCODER.encode(big))
        assert len(data) > 4_000_000
        requests.sendall(data)
        reader = frames.FrameReader(engine.limits.answer_bytes)
        answers.settimeout(30)
        replies = []
        while not replies:
            data = answers.recv(1 << 16)
            assert data, "the engine closed the answers' connection"
            replies = [r for p in reader.feed(data) for r in msg.OUTPUTS_DECODER.decode(p).items if r.id == 5]
    assert replies[0] == msg.Reply(5, 1), replies[0]


@pytest.mark.parametrize("port", ["input", "output"])
def test_a_silent_peer_is_closed_after_the_proof_timeout(engine, monkeypatch, port):
    monkeypatch.setattr(links, "PROOF_TIMEOUT_S", 0.5)
    before = engine.refused("silent")
    with connect(getattr(engine.address, port)) as silent:
        started = time.monotonic()
        assert closed_within(silent, 5), "a peer that sends nothing is kept"
        assert time.monotonic() - started < 3
    assert engine.refused("silent") == before + 1
    status, = engine.ask(msg.Status(1))
    assert msg.decode_result(status, msg.EngineStatus).ready


def test_a_request_for_another_tenants_world_still_answers_not_found(engine):
    """What a proven API process sends is believed as it says: its Access decides (the key's
    worlds only; admin every world)."""
    world = alices_world(engine)
    bob = msg.Access("bob", False, "10.0.0.2")
    refused, = engine.ask(msg.DeleteWorld(1, world, bob))
    assert isinstance(refused, NotFound)
    done, = engine.ask(msg.DeleteWorld(2, world, msg.Access("root", True, "10.0.0.3")))
    assert done is None or not isinstance(done, Exception)
