"""API keys, tenants and the per-key rate limit.

Keys come from ``api_keys`` (``name:token`` entries, comma-separated; ``name:token:admin``
for an admin key) and from ``api_key_file`` (one ``name token [admin]`` per line, ``#``
comments). A request names its key as ``Authorization: Bearer <token>``; a WebSocket may
also use the ``access_token`` query parameter, since browsers cannot set headers on it.
Tokens are compared with ``hmac.compare_digest`` against every configured key.

Each key owns the worlds it creates and sees only those: another tenant's world answers
404, exactly as a world that does not exist. An admin key sees and edits every world. With
no keys configured the server is open (everyone is admin) and ``sdfserver serve`` refuses to
listen on anything but loopback.

``guard`` is the one dependency every ``/v1`` route runs: authenticate, rate-limit
(a token bucket per key — per client address on an open server), and check the owner of
the ``{world_id}`` in the path.
"""

from __future__ import annotations

import hmac
import ipaddress
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fastapi import Request
from starlette.requests import HTTPConnection

from sdfserver.api.bodies import header
from sdfserver.errors import InvalidInput, NotFound, RateLimited, TooLarge, Unauthorized


@dataclass(frozen=True)
class Principal:
    name: str | None  # the key's name; None on an open server
    admin: bool

    def sees(self, owner: str | None) -> bool:
        return self.admin or owner == self.name


OPEN = Principal(None, True)


@dataclass(frozen=True)
class ApiKey:
    name: str
    token: bytes
    admin: bool


def parse_keys(spec: str, key_file: str = "") -> list[ApiKey]:
    entries = [tuple(e.strip().split(":")) for e in spec.split(",") if e.strip()]
    if key_file:
        try:
            lines = Path(key_file).expanduser().read_text().splitlines()
        except OSError as exc:
            raise InvalidInput(f"cannot read api_key_file {key_file}: {exc}") from None
        entries += [tuple(line.split()) for line in lines if line.strip() and not line.lstrip().startswith("#")]
    keys, names = [], set()
    for entry in entries:
        if len(entry) not in (2, 3) or (len(entry) == 3 and entry[2] != "admin"):
            raise InvalidInput("an API key is 'name:token' or 'name:token:admin' (in the file: 'name token "
                               f"[admin]'), got {':'.join(entry[:1])}:...")
        name, token = entry[0], entry[1]
        if len(token) < 16:
            raise InvalidInput(f"the token of API key {name!r} is shorter than 16 characters")
        if name in names:
            raise InvalidInput(f"API key name {name!r} appears twice")
        names.add(name)
        keys.append(ApiKey(name, token.encode(), len(entry) == 3))
    return keys


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class TokenBucket:
    def __init__(self, rate_per_s: float, burst: int):
        self.rate, self.burst = rate_per_s, float(burst)
        self.tokens, self.stamp = float(burst), time.monotonic()

    def take(self) -> float:
        """0 when a token was taken, else the seconds until one is available."""
        now = time.monotonic()
        self.tokens = min(self.burst, self.tokens + (now - self.stamp) * self.rate)
        self.stamp = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return 0.0
        return (1.0 - self.tokens) / self.rate


class Gatekeeper:
    MAX_BUCKETS = 4096  # bounds the per-address buckets of an open server

    def __init__(self, keys: list[ApiKey], rate_per_s: float = 0.0, burst: int = 100):
        self.keys = keys
        self.principals = [Principal(key.name, key.admin) for key in keys]  # built once, not per request
        self.rate_per_s, self.burst = rate_per_s, burst
        self._buckets: dict[str, TokenBucket] = {}
        self._lock = threading.Lock()

    @property
    def open(self) -> bool:
        return not self.keys

    def authenticate(self, token: str | None) -> Principal:
        if self.open:
            return OPEN
        if not token:
            raise Unauthorized("an API key is required: send 'Authorization: Bearer <token>'")
        given = token.encode()
        found = None
        for key, principal in zip(self.keys, self.principals):  # compare with every key, in constant time each
            if hmac.compare_digest(key.token, given):
                found = principal
        if found is None:
            raise Unauthorized("unknown API key")
        return found

    def throttle(self, principal: Principal, client: str) -> None:
        if self.rate_per_s <= 0:
            return
        who = principal.name if principal.name is not None else f"address {client}"
        with self._lock:
            bucket = self._buckets.get(who)
            if bucket is None:
                if len(self._buckets) >= self.MAX_BUCKETS:
                    self._buckets.clear()
                bucket = self._buckets[who] = TokenBucket(self.rate_per_s, self.burst)
            wait = bucket.take()
        if wait:
            raise RateLimited(f"rate limit of {self.rate_per_s:g} requests/s (burst {self.burst}) reached for "
                              f"{who}; retry in {wait:.2f} s", wait)


def bearer_token(connection: HTTPConnection, allow_query: bool = False) -> str | None:
    scheme, _, token = (header(connection, b"authorization") or "").partition(" ")
    if scheme.lower() == "bearer" and token.strip():
        return token.strip()
    if allow_query:
        return connection.query_params.get("access_token")
    return None


def check_owner(engine: Any, principal: Principal, world_id: str) -> None:
    """Another tenant's world is NotFound, word for word as a missing one."""
    if principal.admin:
        return
    if engine.owner_of(world_id) != principal.name:
        raise NotFound(f"no world {world_id!r}")


def admit(gate: Gatekeeper, engine: Any, principal: Principal, client: str, world_id: str | None) -> None:
    """Rate limit and world owner, for a principal already authenticated (here or in a front)."""
    if gate.rate_per_s > 0:
        gate.throttle(principal, client)
    if world_id is not None:
        check_owner(engine, principal, world_id)


def client_host(connection: HTTPConnection) -> str:
    client = connection.client
    return client.host if client else "unknown"


def authenticate(request: Request) -> Principal:
    """The request's key; on an open server it reads none (a few us less) and stores none
    (``principal_of`` answers OPEN)."""
    gate: Gatekeeper = request.app.state.gatekeeper
    if gate.open:
        return OPEN
    principal = gate.authenticate(bearer_token(request))
    request.state.principal = principal
    return principal


async def guard(request: Request) -> None:
    """The dependency of every /v1 route: key, rate limit, world owner."""
    principal = authenticate(request)
    gate: Gatekeeper = request.app.state.gatekeeper
    client = client_host(request) if gate.rate_per_s > 0 else "unknown"  # the address is needed only then
    admit(gate, request.app.state.engine, principal, client, request.path_params.get("world_id"))


def principal_of(request: Request) -> Principal:
    return getattr(request.state, "principal", OPEN)


def check_world_quota(request: Request) -> Principal:
    """The principal creating a world, after checking ``max_worlds_per_key``."""
    principal = principal_of(request)
    limit = request.app.state.settings.max_worlds_per_key
    owners = list(request.app.state.engine.owners.values())
    if not principal.admin and sum(o == principal.name for o in owners) >= limit:
        raise TooLarge(f"API key {principal.name!r} already owns {limit} worlds, its limit")
    return principal
