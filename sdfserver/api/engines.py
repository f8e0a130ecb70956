"""What the routes call: the engines of this server, each request routed by world id.

``Placement`` says which engine holds a world and where a new one goes; ``LocalPlacement``
is the one for engine processes on this machine (a new world goes to the engine with the most
free device memory; a world id not seen yet is looked up on every engine). A distributed
engine (engines as Ray actors, say) implements the same interface.

``Engines`` builds the typed requests (``sdfserver.engine.messages``) and turns their replies
back into what the routes need (NumPy arrays, dicts).
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from sdfserver.api.engine_client import BaseClient
from sdfserver.engine import messages as msg
from sdfserver.errors import Conflict, InvalidInput, NotFound, NotReady, SdfServerError, WorldMoved
from sdfserver.geometry import Box

log = logging.getLogger("sdfserver.api")
STATUS_TIMEOUT_S = 2.0  # an engine that does not answer its status in this long is not ready
MOVE_POLL_S = 0.005  # how often a request for a world on its way to another engine asks again


@dataclass(frozen=True)
class ReadResult:
    origin: tuple[int, int, int]
    version: int
    array: np.ndarray
    content: str = ""  # engine/commands.py ReadResult.content


@dataclass(frozen=True)
class QueryResult:
    version: int
    arrays: dict[str, np.ndarray]  # engine/query.py's ANSWERS[kind]


class Placement(Protocol):
    engines: Sequence[BaseClient]

    async def engine_for(self, world_id: str) -> BaseClient: ...

    async def place(self, config: dict[str, Any]) -> BaseClient: ...

    def placed(self, world_id: str, engine: BaseClient) -> None: ...

    def forget(self, world_id: str) -> None: ...


async def worlds_of(engine: BaseClient) -> list[dict[str, Any]] | None:
    """Every world an engine holds, described; None when it does not answer in STATUS_TIMEOUT_S."""
    try:
        return await asyncio.wait_for(engine.call(msg.Describe(engine.next_id(), None)), STATUS_TIMEOUT_S)
    except asyncio.TimeoutError:
        return None


class LocalPlacement:
    def __init__(self, engines: Sequence[BaseClient]):
        self.engines = list(engines)
        self._where: dict[str, BaseClient] = {}

    async def engine_for(self, world_id: str) -> BaseClient:
        if len(self.engines) == 1:
            return self.engines[0]
        engine = self._where.get(world_id)
        if engine is None:  # created by another API process, restored or moved: ask every engine
            lists = await asyncio.gather(*(worlds_of(e) for e in self.engines))
            epochs: dict[str, int] = {}
            for candidate, worlds in zip(self.engines, lists):
                for world in worlds or ():  # an engine that missed its world being taken over has an older epoch
                    if world.get("epoch", 0) >= epochs.get(world["id"], -1):
                        epochs[world["id"]] = world.get("epoch", 0)
                        self._where[world["id"]] = candidate
            engine = self._where.get(world_id)
            silent = [i for i, worlds in enumerate(lists) if worlds is None]
            if engine is None and silent:
                raise NotReady(f"world {world_id!r} is on no engine that answered; engine {silent[0]} did not "
                               f"answer in {STATUS_TIMEOUT_S:g} s")
        if engine is None:
            raise NotFound(f"no world {world_id!r}")
        return engine

    async def place(self, config: dict[str, Any]) -> BaseClient:
        if len(self.engines) == 1:
            return self.engines[0]
        statuses = await asyncio.gather(*(e.call(msg.Status(e.next_id())) for e in self.engines))
        free = [msg.decode_result(s, msg.EngineStatus).free_bytes for s in statuses]
        return self.engines[int(np.argmax(free))]

    def placed(self, world_id: str, engine: BaseClient) -> None:
        self._where[world_id] = engine

    def forget(self, world_id: str) -> None:
        self._where.pop(world_id, None)


class Engines:
    def __init__(self, placement: Placement, max_wait_s: float):
        self.placement = placement
        self.max_wait_s = max_wait_s
        self._subscription_numbers = iter(range(1, 1 << 62))

    @property
    def clients(self) -> Sequence[BaseClient]:
        return self.placement.engines

    async def _call(self, world_id: str, make: Callable[[int], Any],
                    asking: Callable[[BaseClient], None] = lambda engine: None) -> Any:
        """``make(request id)``'s request sent to the world's engine (``asking`` is told which)."""
        engine = await self.placement.engine_for(world_id)
        asking(engine)
        try:
            return await engine.call(make(engine.next_id()))
        except (WorldMoved, NotFound):
            if len(self.clients) == 1:
                raise
        return await self._call_after_move(world_id, make, asking)

    async def _call_after_move(self, world_id: str, make: Callable[[int], Any],
                               asking: Callable[[BaseClient], None]) -> Any:
        """Ask again where the world is: it moved (or is moving) to another engine. Until it
        arrives there (at most ``max_wait_s``) the engines answer WorldMoved or NotFound; a world
        that no engine has and none has seen leave is not found."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.max_wait_s
        moving = False
        while True:
            self.placement.forget(world_id)
            try:
                engine = await self.placement.engine_for(world_id)
                asking(engine)
                return await engine.call(make(engine.next_id()))
            except WorldMoved:
                moving = True
                if loop.time() >= deadline:
                    raise
            except NotFound:
                if not moving or loop.time() >= deadline:
                    raise
            await asyncio.sleep(MOVE_POLL_S)

    # -- worlds --------------------------------------------------------------------------------

    async def create_world(self, config: dict[str, Any], access: msg.Access | None,
                           voxels: np.ndarray | None = None, max_owned: int = 0,
                           sparse_snapshot: bytes | None = None) -> dict[str, Any]:
        """A new world: empty, generated, or imported (dense ``voxels``, or a sparse world's
        snapshot file, which its engine checks)."""
        engine = await self.placement.place(config)
        elsewhere = 0
        if len(self.clients) > 1 and access is not None and not access.admin and max_owned:
            for other in self.clients:
                if other is not engine:
                    worlds = await other.call(msg.Describe(other.next_id(), None, access))
                    elsewhere += len(worlds)
        blob = None if voxels is None else msg.Array.of(voxels)
        described = await engine.call(msg.CreateWorld(engine.next_id(), config, access, blob, max_owned, elsewhere,
                                                      sparse_snapshot))
        self.placement.placed(described["id"], engine)
        return described

    async def export_bricks(self, world_id: str, access: msg.Access | None) -> bytes:
        """A sparse world as a snapshot file (its brick table and stored bricks)."""
        return await self._call(world_id, lambda i: msg.ExportBricks(i, world_id, access))

    async def delete_world(self, world_id: str, access: msg.Access | None) -> None:
        await self._call(world_id, lambda i: msg.DeleteWorld(i, world_id, access))
        self.placement.forget(world_id)

    async def move_world(self, world_id: str, target: int, access: msg.Access | None,
                         release_timeout_s: float) -> dict[str, Any]:
        """Move a world to engine ``target``: released by its holder (its batches so far durable,
        its directory handed over) and adopted by the target. A holder that does not answer in
        ``release_timeout_s`` is taken over: the target fetches the directory and its new epoch
        fences the old holder. If the target cannot take the world, its holder takes it back."""
        if not 0 <= target < len(self.clients):
            raise InvalidInput(f"engine must be 0..{len(self.clients) - 1}, got {target}")
        for attempt in range(2):
            source = await self.placement.engine_for(world_id)
            origin = list(self.clients).index(source)
            if origin == target:
                raise Conflict(f"world {world_id!r} is already on engine {target}")
            taken_from = None
            try:
                await asyncio.wait_for(source.call(msg.ReleaseWorld(source.next_id(), world_id, target, access)),
                                       release_timeout_s)
                break
            except (WorldMoved, NotFound):  # where this process saw it last is out of date: look again
                self.placement.forget(world_id)
                if attempt:
                    raise
            except (asyncio.TimeoutError, NotReady):
                taken_from = origin  # the holder does not answer: its directory is fetched, it is fenced
                break
        destination = self.clients[target]
        self.placement.forget(world_id)
        try:
            described = await destination.call(msg.AdoptWorld(destination.next_id(), world_id, taken_from, access))
        except Exception:
            if taken_from is None:  # handed over but not taken (no room there, say): back to its holder
                await source.call(msg.AdoptWorld(source.next_id(), world_id, target, access))
            raise
        self.placement.placed(world_id, destination)
        return {**described, "engine": target}

    async def rebalance(self, below: float, release_timeout_s: float) -> list[dict[str, Any]]:
        """One pass: each engine whose free memory is under ``below`` of its budget moves its
        smallest world that fits to the engine with the most free memory (which stays above the
        mark). Returns the moves made: [{world, from, to, bytes, ms}]."""
        statuses = await self.status()
        lists = [worlds or [] for worlds in await asyncio.gather(*(worlds_of(e) for e in self.clients))]
        free = [s.free_bytes if s.ready else 0 for s in statuses]
        moves = []
        for short, status in enumerate(statuses):
            if not status.ready or status.budget_bytes <= 0 or free[short] >= below * status.budget_bytes:
                continue
            roomiest = max((i for i, s in enumerate(statuses) if i != short and s.ready), key=lambda i: free[i],
                           default=None)
            if roomiest is None:
                continue
            room = free[roomiest] - below * statuses[roomiest].budget_bytes
            fitting = sorted((w["device_bytes"], w["id"]) for w in lists[short] if w["device_bytes"] <= room)
            if not fitting:
                continue
            size, world_id = fitting[0]
            started = asyncio.get_running_loop().time()
            await self.move_world(world_id, roomiest, None, release_timeout_s)
            free[short] += size
            free[roomiest] -= size
            moves.append({"world": world_id, "from": short, "to": roomiest, "bytes": size,
                          "ms": round((asyncio.get_running_loop().time() - started) * 1e3, 1)})
        return moves

    async def rebalance_forever(self, below: float, every_s: float, release_timeout_s: float,
                                leading: Callable[[], bool]) -> None:
        """``rebalance`` every ``every_s`` seconds while ``leading()`` (one API process of all)."""
        while True:
            await asyncio.sleep(every_s)
            if not leading():
                continue
            try:
                for move in await self.rebalance(below, release_timeout_s):
                    log.info("rebalanced: world %s from engine %d to %d (%d bytes, %.1f ms)", move["world"],
                             move["from"], move["to"], move["bytes"], move["ms"])
            except SdfServerError as exc:  # an engine not ready, a world that moved meanwhile: next time
                log.warning("rebalancing failed, tried again in %g s: %s", every_s, exc)

    async def reconfigure(self, world_id: str, changes: dict[str, Any], access: msg.Access | None) -> None:
        await self._call(world_id, lambda i: msg.Reconfigure(i, world_id, changes, access))

    async def describe(self, world_id: str, access: msg.Access | None = None) -> dict[str, Any]:
        engine = await self.placement.engine_for(world_id)
        described = await engine.call(msg.Describe(engine.next_id(), world_id, access))
        return {**described, "engine": list(self.clients).index(engine)}

    async def list_worlds(self, access: msg.Access | None = None) -> list[dict[str, Any]]:
        lists = await asyncio.gather(*(e.call(msg.Describe(e.next_id(), None, access)) for e in self.clients))
        return sorted(({**w, "engine": i} for i, worlds in enumerate(lists) for w in worlds), key=lambda w: w["id"])

    # -- the hot requests ------------------------------------------------------------------------

    async def apply_edits(self, world_id: str, batch: bytes, access: msg.Access | None) -> int:
        return await self._call(world_id, lambda i: msg.ApplyEdits(i, world_id, batch, access))

    async def read(self, world_id: str, kind: str, box: Box | None = None, min_version: int = 0,
                   access: msg.Access | None = None) -> ReadResult:
        lo, hi = (None, None) if box is None else (box.lo, box.hi)
        raw = await self._call(world_id, lambda i: msg.Read(i, world_id, kind, lo, hi, min_version, access))
        result = msg.decode_result(raw, msg.ReadResult)
        return ReadResult(tuple(result.origin), result.version, result.array.numpy(), result.content)

    async def query(self, world_id: str, rows: np.ndarray, min_version: int = 0,
                    access: msg.Access | None = None, kind: str = "points") -> QueryResult:
        blob = msg.Array.view(np.asarray(rows))  # encoded as it is sent, in this call
        raw = await self._call(world_id, lambda i: msg.Query(i, world_id, blob, min_version, access, kind))
        r = msg.decode_result(raw, msg.QueryResult)
        return QueryResult(r.version, {name: a.numpy() for name, a in r.arrays.items()})

    async def render(self, world_id: str, view: dict[str, Any], unless_field_version: int | None = None,
                     access: msg.Access | None = None) -> msg.Frame | None:
        raw = await self._call(world_id, lambda i: msg.Render(i, world_id, view, unless_field_version, access))
        return None if raw is None else msg.decode_result(raw, msg.Frame)

    async def pick(self, world_id: str, view: dict[str, Any], x: float, y: float,
                   access: msg.Access | None = None) -> msg.PickResult:
        raw = await self._call(world_id, lambda i: msg.Pick(i, world_id, view, x, y, access))
        return msg.decode_result(raw, msg.PickResult)

    # -- subscriptions and access ---------------------------------------------------------------

    async def subscribe(self, world_id: str, region: Box, fmt: str, access: msg.Access | None,
                        deliver: Callable[[msg.ChunkUpdate], None]) -> tuple[BaseClient, int]:
        """Subscribe on the engine that holds the world (asked again while it moves)."""
        number = next(self._subscription_numbers)
        held: list[BaseClient] = []

        def asking(engine: BaseClient) -> None:  # updates may come before the answer
            if held:
                held[0].on_updates(number, None)
            held[:] = [engine]
            engine.on_updates(number, deliver)

        try:
            await self._call(world_id, lambda i: msg.Subscribe(i, world_id, number, region.lo, region.hi, fmt, access),
                             asking)
        except BaseException:
            if held:
                held[0].on_updates(number, None)
            raise
        return held[0], number

    def taken(self, engine: BaseClient, number: int) -> None:
        """The subscriber sent what it had: the engine may send the next update."""
        engine.tell(msg.Taken(0, number))

    def unsubscribe(self, engine: BaseClient, number: int) -> None:
        engine.on_updates(number, None)
        engine.tell(msg.Unsubscribe(0, number))

    async def admit(self, access: msg.Access, world_id: str | None = None) -> None:
        if world_id is None:
            engine = self.clients[0]  # the rate limit's buckets live in the first engine
            await engine.call(msg.Admit(engine.next_id(), access))
        else:
            await self._call(world_id, lambda i: msg.Admit(i, access, world_id))

    # -- health and metrics ----------------------------------------------------------------------

    async def status(self) -> list[msg.EngineStatus]:
        async def one(engine: BaseClient) -> msg.EngineStatus:
            if engine.lost is not None:
                return msg.EngineStatus(False, engine.lost, "", 0)
            try:
                raw = await asyncio.wait_for(engine.call(msg.Status(engine.next_id())), STATUS_TIMEOUT_S)
            except asyncio.TimeoutError:
                return msg.EngineStatus(False, f"the engine did not answer in {STATUS_TIMEOUT_S:g} s", "", 0)
            return msg.decode_result(raw, msg.EngineStatus)

        return list(await asyncio.gather(*(one(e) for e in self.clients)))

    async def metrics_text(self) -> str:
        texts = await asyncio.gather(*(e.call(msg.MetricsText(e.next_id())) for e in self.clients))
        return merge_metrics(list(texts))

    def count(self, bytes_out: int = 0, websocket_clients: int = 0) -> None:
        self.clients[0].tell(msg.CountApi(0, bytes_out, websocket_clients))


def merge_metrics(texts: list[str]) -> str:
    """Several engines' Prometheus texts as one exposition: each family once (a family may not
    appear twice), each sample labelled with its engine's index."""
    if len(texts) == 1:
        return texts[0]
    from prometheus_client import CollectorRegistry, generate_latest
    from prometheus_client.parser import text_string_to_metric_families
    from prometheus_client.samples import Sample

    families: dict[str, Any] = {}
    for index, text in enumerate(texts):
        for family in text_string_to_metric_families(text):
            samples = [Sample(s.name, {**s.labels, "engine": str(index)}, s.value, s.timestamp, s.exemplar)
                       for s in family.samples]
            if family.name in families:
                families[family.name].samples.extend(samples)
            else:
                family.samples = samples
                families[family.name] = family

    class Merged:
        def collect(self) -> list[Any]:
            return list(families.values())

    registry = CollectorRegistry(auto_describe=False)
    registry.register(Merged())
    return generate_latest(registry).decode()


def not_ready(statuses: list[msg.EngineStatus]) -> NotReady | None:
    for status in statuses:
        if not status.ready:
            return NotReady(status.reason or "the engine is not ready")
    return None
