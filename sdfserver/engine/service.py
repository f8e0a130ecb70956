"""The engine's answers to typed requests: one handler per message type.

``EngineService.handle(client, request)`` runs on the engine process's input thread: it
checks access (rate limit, owner), turns the request into an engine command, submits it and
leaves a callback on its future that hands the ``Reply`` to ``send(client, item)``, the
output side. Requests that need no engine step (status, metrics, admission) are answered at
once. Subscriptions keep their single-slot mailbox here; ``send`` is told which one has
news, and the output side takes whatever it holds when it sends.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable

from prometheus_client import generate_latest

from sdfserver.engine import commands as cmd
from sdfserver.engine import messages as msg
from sdfserver.engine.access import Doorkeeper, holder_of
from sdfserver.engine.core import Engine
from sdfserver.engine.mailbox import Mailbox, Subscription
from sdfserver.engine.rebuild import config_from_dict
from sdfserver.errors import Forbidden, InvalidInput, SdfServerError, TooManySubscriptions
from sdfserver.geometry import Box
from sdfserver.incoming import short
from sdfserver.render import parse_view
from sdfserver.storage.codec import decode_edits
from sdfserver.storage.snapshot import encode_snapshot, sparse_upload
from sdfserver.world import Focus

log = logging.getLogger("sdfserver.engine")
Send = Callable[[bytes, Any], None]  # (client, Reply | a subscription with news)


class SubscriptionNews:
    """Told to the output side: ``subscription`` of ``client`` has chunks waiting."""

    __slots__ = ("number", "subscription")

    def __init__(self, number: int, subscription: Subscription):
        self.number = number
        self.subscription = subscription


class EngineService:
    def __init__(self, engine: Engine, doorkeeper: Doorkeeper, send: Send, *, writes_failure:
                 Callable[[], str | None] = lambda: None, data_dir_of: Callable[[int], Path] | None = None,
                 epoch: int = 0):
        """``data_dir_of(i)``: engine i's data directory, for moves (None: this engine has no peers)."""
        self.engine = engine
        self.doorkeeper = doorkeeper
        self.send = send
        self.writes_failure = writes_failure
        self.data_dir_of = data_dir_of
        self.epoch = epoch
        self._exports = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sdfserver-export")
        self.subscriptions: dict[tuple[bytes, int], Subscription] = {}
        self._holders: dict[tuple[bytes, int], str] = {}  # each subscription's key (or client address)
        # a subscription with credit may be sent its next update; sending spends it, ``Taken`` returns it
        self._credit: dict[tuple[bytes, int], bool] = {}
        self._credit_lock = threading.Lock()
        self.handlers: dict[type, Callable[[bytes, Any], None]] = {
            msg.CreateWorld: self._create, msg.DeleteWorld: self._delete, msg.Reconfigure: self._reconfigure,
            msg.ReleaseWorld: self._release, msg.AdoptWorld: self._adopt, msg.ExportBricks: self._export,
            msg.Describe: self._describe, msg.ApplyEdits: self._apply, msg.Read: self._read,
            msg.Query: self._query, msg.Render: self._render, msg.Pick: self._pick,
            msg.Subscribe: self._subscribe, msg.Unsubscribe: self._unsubscribe, msg.Taken: self._taken,
            msg.Admit: self._admit, msg.Status: self._status, msg.MetricsText: self._metrics,
            msg.CountApi: self._count,
        }

    def handle(self, client: bytes, request: Any) -> None:
        try:
            self.handlers[type(request)](client, request)
        except Exception as exc:  # refused before reaching the engine: that request alone fails
            if not isinstance(exc, SdfServerError):
                log.exception("a request failed unexpectedly", exc_info=exc)
            self._reply(client, request.id, failure=exc)

    def forget(self, client: bytes) -> None:
        """Drop the subscriptions of an API process that is gone."""
        for key in list(self.subscriptions):  # a copy: the input thread may change it meanwhile
            if key[0] == client:
                subscription = self._drop(key)
                if subscription is not None:
                    self.engine.unsubscribe(subscription)

    def update_for(self, client: bytes, news: SubscriptionNews) -> msg.ChunkUpdate | None:
        """Output side: the subscription's pending chunks, if it may be sent them now."""
        key = (client, news.number)
        with self._credit_lock:
            if not self._credit.get(key) or self.subscriptions.get(key) is not news.subscription:
                return None
            update = chunk_update(news)
            if update is not None:
                self._credit[key] = False
            return update

    # -- replies ------------------------------------------------------------------------------

    def _reply(self, client: bytes, request_id: int, result: Any = None, failure: BaseException | None = None):
        if request_id:
            self.send(client, msg.Reply(request_id, result, None if failure is None else msg.failure_of(failure)))

    def _submit(self, client: bytes, request_id: int, command: Any,
                convert: Callable[[Any], Any] = lambda r: r) -> None:
        def done(result: Any, exc: BaseException | None) -> None:
            if exc is not None:
                self._reply(client, request_id, failure=exc)
                return
            try:
                result = convert(result)
            except Exception as exc:
                self._reply(client, request_id, failure=exc)
            else:
                self._reply(client, request_id, result)

        self.engine.submit(command, on_done=done)

    # -- the handlers -------------------------------------------------------------------------

    def _create(self, client: bytes, m: msg.CreateWorld) -> None:
        self.doorkeeper.admit(m.access)
        self.doorkeeper.check_quota(m.access, m.max_owned, m.owned_elsewhere)
        try:
            config = config_from_dict(m.config)
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInput(f"bad world configuration: {exc!r}") from None
        voxels = None if m.voxels is None else m.voxels.numpy()
        if m.snapshot is not None:  # a sparse world's file: checked here, where the world will live
            voxels = sparse_upload(m.snapshot, config, self.engine.limits.max_read_voxels)
        owner = m.access.key if m.access is not None else None
        self._submit(client, m.id, cmd.CreateWorld(config, None, owner, voxels))

    def _delete(self, client: bytes, m: msg.DeleteWorld) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        self._submit(client, m.id, cmd.DeleteWorld(m.world_id))

    def _reconfigure(self, client: bytes, m: msg.Reconfigure) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        changes = dict(m.changes)
        if "focus" in changes and changes["focus"] is not None:
            focus = changes["focus"]
            changes["focus"] = Focus(tuple(focus["center"]), tuple(focus["size"]))
        self._submit(client, m.id, cmd.Reconfigure(m.world_id, changes))

    def _release(self, client: bytes, m: msg.ReleaseWorld) -> None:
        self._check_move(m.access)
        self._submit(client, m.id, cmd.ReleaseWorld(m.world_id, self._peer_dir(m.destination)))

    def _adopt(self, client: bytes, m: msg.AdoptWorld) -> None:
        self._check_move(m.access)
        source = None if m.source is None else self._peer_dir(m.source)
        self._submit(client, m.id, cmd.AdoptWorld(m.world_id, source))

    def _export(self, client: bytes, m: msg.ExportBricks) -> None:
        """The bricks are copied on the engine thread and encoded (zlib) on the export thread."""
        self.doorkeeper.admit(m.access, m.world_id)
        future = self.engine.submit(cmd.CopyBricks(m.world_id))

        def encode(copied: tuple) -> bytes:
            version, config, content, wait = copied
            wait()
            return encode_snapshot(version, config, content)

        def done(future: Future) -> None:
            if future.exception() is not None:
                self._reply(client, m.id, failure=future.exception())
                return
            encoded = self._exports.submit(encode, future.result())
            encoded.add_done_callback(lambda e: self._reply(client, m.id, e.result()) if e.exception() is None
                                      else self._reply(client, m.id, failure=e.exception()))

        future.add_done_callback(done)

    def _check_move(self, access: msg.Access | None) -> None:
        self.doorkeeper.admit(access)
        if access is not None and not access.admin:
            raise Forbidden("moving a world between engines needs an admin key")
        if self.data_dir_of is None:
            raise InvalidInput("this engine has no other engine to move worlds to or from")

    def _peer_dir(self, index: int) -> Path:
        try:
            return self.data_dir_of(index)
        except (IndexError, ValueError) as exc:
            raise InvalidInput(f"no engine {index}: {exc}") from None

    def _describe(self, client: bytes, m: msg.Describe) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        if m.world_id is not None or m.access is None or m.access.admin:
            self._submit(client, m.id, cmd.Describe(m.world_id))
            return
        key = m.access.key
        self._submit(client, m.id, cmd.Describe(None), lambda worlds: [w for w in worlds if w["owner"] == key])

    def _apply(self, client: bytes, m: msg.ApplyEdits) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        edits, batch_id = decode_edits(m.batch, "edit batch")
        self._submit(client, m.id, cmd.ApplyEdits(m.world_id, edits, m.batch, batch_id))

    def _read(self, client: bytes, m: msg.Read) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        if m.kind not in ("packed", "distance", "voxels"):
            raise InvalidInput(f"unknown read kind {short(m.kind)}")
        box = None if m.lo is None or m.hi is None else Box(m.lo, m.hi)
        command = cmd.Read(m.world_id, m.kind, box, m.min_version, self._deadline())
        self._submit(client, m.id, command,
                     lambda r: msg.ReadResult(tuple(r.origin), r.version, msg.Array.of(r.array), r.content))

    def _query(self, client: bytes, m: msg.Query) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        command = cmd.Query(m.world_id, m.rows.numpy(), m.min_version, self._deadline(), m.kind)
        self._submit(client, m.id, command, lambda r: msg.QueryResult(
            r.version, {name: msg.Array.view(a) for name, a in r.arrays.items()}))  # a new buffer each query

    def _render(self, client: bytes, m: msg.Render) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        camera, options = parse_view(m.view)

        def frame(result: Any) -> msg.Frame | None:
            if result is None:
                return None
            drawn, field_ms = result
            return msg.Frame(msg.Array.of(drawn.pixels), drawn.field_version, drawn.device_ms, field_ms)

        self._submit(client, m.id, cmd.Draw(m.world_id, camera, options, m.unless_field_version), frame)

    def _pick(self, client: bytes, m: msg.Pick) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        camera, _ = parse_view(m.view)

        def picked(result: Any) -> msg.PickResult:
            hit, version = result
            if hit is None:
                return msg.PickResult(version)
            return msg.PickResult(version, tuple(hit.voxel), tuple(hit.normal), tuple(hit.place))

        self._submit(client, m.id, cmd.PickAt(m.world_id, camera, m.x, m.y), picked)

    def _subscribe(self, client: bytes, m: msg.Subscribe) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        if m.format not in ("packed", "distance"):
            raise InvalidInput(f"format must be 'distance' or 'packed', got {short(m.format)}")
        key = (client, m.subscription)
        self._check_room(key, m.access)
        old = self.subscriptions.pop(key, None)
        if old is not None:
            self.engine.unsubscribe(old)
        subscription = Subscription(m.world_id, Box(m.lo, m.hi), m.format)
        news = SubscriptionNews(m.subscription, subscription)
        subscription.mailbox = Mailbox(lambda: self.send(client, news))
        self.subscriptions[key] = subscription
        with self._credit_lock:
            self._credit[key] = True

        future = self.engine.submit(cmd.Subscribe(subscription))

        def done(future: Future) -> None:
            exc = future.exception()
            if exc is not None and self.subscriptions.get(key) is subscription:
                self._drop(key)
            self._reply(client, m.id, None, exc)

        future.add_done_callback(done)

    def _drop(self, key: tuple[bytes, int]) -> Subscription | None:
        """Forget a subscription's state (the engine's side is the caller's to end)."""
        self._credit.pop(key, None)
        self._holders.pop(key, None)
        return self.subscriptions.pop(key, None)

    def _check_room(self, key: tuple[bytes, int], access: msg.Access | None) -> None:
        """Refuse a new subscription past the engine's limits; replacing one's region is not new."""
        if key in self.subscriptions:
            return
        limits = self.engine.limits
        if len(self.subscriptions) >= limits.max_subscriptions:
            raise TooManySubscriptions(f"this engine holds {limits.max_subscriptions} subscriptions, "
                                       "its limit (max_subscriptions); try again later")
        holder = "" if access is None else holder_of(access)
        held = sum(1 for who in self._holders.values() if who == holder)
        if held >= limits.max_subscriptions_per_key:
            raise TooManySubscriptions(f"{holder or 'this client'} holds {limits.max_subscriptions_per_key} "
                                       "subscriptions, its limit (max_subscriptions_per_key)")
        self._holders[key] = holder

    def _unsubscribe(self, client: bytes, m: msg.Unsubscribe) -> None:
        subscription = self._drop((client, m.subscription))
        if subscription is not None:
            self.engine.unsubscribe(subscription)
        self._reply(client, m.id)

    def _taken(self, client: bytes, m: msg.Taken) -> None:
        key = (client, m.subscription)
        subscription = self.subscriptions.get(key)
        if subscription is None:
            return
        with self._credit_lock:
            self._credit[key] = True
        if subscription.mailbox.pending:  # what merged meanwhile goes now, or that it ended
            self.send(client, SubscriptionNews(m.subscription, subscription))

    def _admit(self, client: bytes, m: msg.Admit) -> None:
        self.doorkeeper.admit(m.access, m.world_id)
        self._reply(client, m.id)

    def _status(self, client: bytes, m: msg.Status) -> None:
        engine = self.engine
        gpu = engine.gpu
        free = max(0, gpu.memory_budget_bytes - sum(w.device_bytes for w in list(engine.worlds.values())))
        self._reply(client, m.id, msg.EngineStatus(engine.ready, None if engine.ready else engine.not_ready_reason(),
                                                   gpu.device_name, free, self.writes_failure(), os.getpid(),
                                                   list(engine.worlds), self.epoch, gpu.memory_budget_bytes,
                                                   engine.busy()))

    def _metrics(self, client: bytes, m: msg.MetricsText) -> None:
        self._reply(client, m.id, generate_latest(self.engine.metrics.registry).decode())

    def _count(self, client: bytes, m: msg.CountApi) -> None:
        metrics = self.engine.metrics
        if m.bytes_out:
            metrics.bytes_out.inc(m.bytes_out)
        if m.websocket_clients:
            metrics.ws_clients.inc(m.websocket_clients)
        self._reply(client, m.id)

    def _deadline(self) -> float:
        return time.monotonic() + self.engine.max_wait_s


def chunk_update(news: SubscriptionNews) -> msg.ChunkUpdate | None:
    """What a subscription's mailbox holds, taken now (output side)."""
    update = news.subscription.mailbox.take()
    if update is None:
        return None
    return msg.ChunkUpdate(news.number, update.version, [(k, v) for k, v in update.chunks.items()], update.ended)

