"""How many wrong passwords each client address may still send: a token bucket each.

A check takes a token before its scrypt runs (so a hundred guesses sent at once
cannot all get in before the first fails) and gives it back when the password
was right. An empty bucket means "429, retry after N s" without any scrypt. The
table is bounded: full buckets carry nothing and are forgotten first. This module
knows no HTTP and no clock but the one it is given.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class FailureBudget:
    def __init__(
        self,
        burst: int,
        refill_s: float,
        *,
        clock: Callable[[], float] = time.monotonic,
        max_clients: int = 4096,
    ) -> None:
        if burst < 1 or refill_s <= 0:
            raise ValueError(f"burst {burst} must be >= 1 and refill_s {refill_s} > 0")
        self._burst = float(burst)
        self._refill_s = refill_s
        self._clock = clock
        self._max = max_clients
        self._buckets: dict[str, tuple[float, float]] = {}  # client: (tokens, at)

    def _tokens(self, client: str, now: float) -> float:
        tokens, at = self._buckets.get(client, (self._burst, now))
        return min(self._burst, tokens + (now - at) / self._refill_s)

    def take(self, client: str) -> float:
        """Take a token: 0.0 if there was one, else the seconds until there will be."""
        now = self._clock()
        tokens = self._tokens(client, now)
        if tokens < 1.0:
            return (1.0 - tokens) * self._refill_s
        self._forget(now)
        self._buckets[client] = (tokens - 1.0, now)
        return 0.0

    def refund(self, client: str) -> None:
        """The password was right: what `take` took is given back."""
        now = self._clock()
        if client in self._buckets:
            self._buckets[client] = (min(self._burst, self._tokens(client, now) + 1.0), now)

    def _forget(self, now: float) -> None:
        if len(self._buckets) < self._max:
            return
        for client in [c for c in self._buckets if self._tokens(c, now) >= self._burst]:
            del self._buckets[client]
        if len(self._buckets) >= self._max:  # a table of busy guessers: the stalest go
            by_age = sorted(self._buckets, key=lambda c: self._buckets[c][1])
            for client in by_age[: len(by_age) // 2]:
                del self._buckets[client]
