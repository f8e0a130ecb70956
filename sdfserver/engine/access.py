"""Who may do what, checked in the engine process for every API process at once: the
per-key rate limit (one token bucket per key, or per client address on an open server) and
the owner of a world (another tenant's world is NotFound, word for word as a missing one).

An ``Access`` is believed as it is sent: the engine never sees API tokens, so it cannot check the
key itself. That is safe only because every request reaches the engine from an API process that
has proven it holds the engine's credential, or over a Unix socket only the server's user can
open (``links.py``; ``docs/reliability.md``, "Links")."""

from __future__ import annotations

import threading
import time
from typing import Callable

from sdfserver.engine.messages import Access
from sdfserver.errors import NotFound, RateLimited, TooLarge


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


class RateLimiter:
    MAX_BUCKETS = 4096  # bounds the per-address buckets of an open server

    def __init__(self, rate_per_s: float = 0.0, burst: int = 100):
        self.rate_per_s, self.burst = rate_per_s, burst
        self._buckets: dict[str, TokenBucket] = {}
        self._lock = threading.Lock()

    def throttle(self, who: str) -> None:
        if self.rate_per_s <= 0:
            return
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


def holder_of(access: Access) -> str:
    """Whose budget a request spends: its key, or on an open server its client's address."""
    return access.key if access.key is not None else f"address {access.client}"


class Doorkeeper:
    """The rate limit and the owner check of one engine, for requests carrying an ``Access``."""

    def __init__(self, limiter: RateLimiter, owner_of: Callable[[str], str | None],
                 owners: Callable[[], list[str | None]]):
        self.limiter = limiter
        self.owner_of = owner_of  # NotFound for an unknown world
        self.owners = owners

    def admit(self, access: Access | None, world_id: str | None = None) -> None:
        if access is None:
            return
        if self.limiter.rate_per_s > 0:
            self.limiter.throttle(holder_of(access))
        if world_id is not None and not access.admin and self.owner_of(world_id) != access.key:
            raise NotFound(f"no world {world_id!r}")

    def check_quota(self, access: Access | None, max_owned: int, owned_elsewhere: int) -> None:
        if access is None or access.admin or max_owned <= 0:
            return
        owned = owned_elsewhere + sum(owner == access.key for owner in self.owners())
        if owned >= max_owned:
            raise TooLarge(f"API key {access.key!r} already owns {max_owned} worlds, its limit")
