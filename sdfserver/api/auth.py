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

``guard`` is the one dependency every ``/v1`` route runs: it authenticates and leaves the
request's ``Access`` for the engine, which rate-limits (a token bucket per key — per client
address on an open server) and checks the owner of the world, in one place for every API
process.
"""

from __future__ import annotations

import hmac
import ipaddress
from dataclasses import dataclass
from pathlib import Path

from fastapi import Request
from starlette.requests import HTTPConnection

from sdfserver.api.bodies import header
from sdfserver.engine.messages import Access
from sdfserver.errors import InvalidInput, Unauthorized


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


class Gatekeeper:
    """The keys, in every API process alike; the rate limit and the owners are the engine's
    (``sdfserver/engine/access.py``), so that N API processes share one budget per key."""

    def __init__(self, keys: list[ApiKey], rate_per_s: float = 0.0):
        self.keys = keys
        self.principals = [Principal(key.name, key.admin) for key in keys]  # built once, not per request
        self.rate_per_s = rate_per_s

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

    def access(self, principal: Principal, client: str) -> Access | None:
        """What the engine checks for this principal; None when there is nothing to check."""
        if self.open and self.rate_per_s <= 0:
            return None
        return Access(principal.name, principal.admin, client)


def bearer_token(connection: HTTPConnection, allow_query: bool = False) -> str | None:
    scheme, _, token = (header(connection, b"authorization") or "").partition(" ")
    if scheme.lower() == "bearer" and token.strip():
        return token.strip()
    if allow_query:
        return connection.query_params.get("access_token")
    return None


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
    """The dependency of every /v1 route: the key here; its rate limit and the world's owner
    are checked by the engine with the request's ``access``."""
    principal = authenticate(request)
    gate: Gatekeeper = request.app.state.gatekeeper
    request.state.access = gate.access(principal, client_host(request))


def principal_of(request: Request) -> Principal:
    return getattr(request.state, "principal", OPEN)


def access_of(request: Request) -> Access | None:
    return getattr(request.state, "access", None)
