"""How many connections the daemon's sockets hold: caps per peer and in all, and
descriptors kept in reserve for the serial port and the journal.

Each connection a socket keeps is a file descriptor, and the process has a fixed
number (RLIMIT_NOFILE: 1,024 under systemd's default). A client that holds many
connections must not take the ones the daemon needs to reopen its serial port,
write its journal and spill files, or talk to the sonde. So:
- `Admission` caps the connections one socket holds, in all and per peer (uid):
  one user's flood refuses only that user once its share is taken;
- `DescriptorBudget`, shared by every socket, admits a connection only while more
  than `RESERVE` descriptors would stay free after it; it counts the process's
  open descriptors at most once a second;
- `RequestRate` bounds the connections one peer may make a minute (on the
  control socket each request may log, journal and move the winch).

It never blocks, never opens more than one descriptor (to count them) and never
logs: the sockets say what they refused.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field

# Descriptors no socket client may take: the serial port (reopened after a loss),
# the journal with its -wal and -shm, SQLite's temporary files, spill files, the
# sonde's and sonar's ports, the GPIO chip, the log. The daemon itself holds about
# 20 with the simulated winch (benchmarks/socket_attacks.py prints its most); these
# cover what it may open on top.
RESERVE = 64
_RECOUNT_S = 1.0


def open_descriptors() -> int | None:
    """How many descriptors this process has open (None: the kernel cannot say)."""
    for listing in ("/proc/self/fd", "/dev/fd"):
        try:
            return len(os.listdir(listing)) - 1  # less the listing's own
        except OSError:
            continue
    return None


def descriptor_limit() -> int:
    import resource

    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    return soft if soft != resource.RLIM_INFINITY else 1 << 20


class DescriptorBudget:
    """The descriptors every socket's clients may hold together, keeping `reserve`
    free. `count` and `limit` are the process's (replaced in tests)."""

    def __init__(
        self,
        reserve: int = RESERVE,
        *,
        count: Callable[[], int | None] = open_descriptors,
        limit: Callable[[], int] = descriptor_limit,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.reserve = reserve
        self._count = count
        self._limit = limit
        self._clock = clock
        self.held = 0
        self._free = 0  # free descriptors at the last count, less those taken since
        self._counted_at: float | None = None

    def take(self) -> bool:
        now = self._clock()
        if self._counted_at is None or now - self._counted_at >= _RECOUNT_S:
            opened = self._count()
            # Unknown: assume the clients we hold are all there is beside the reserve.
            self._free = self._limit() - (opened if opened is not None else self.held)
            self._counted_at = now
        if self._free <= self.reserve:
            return False
        self.held += 1
        self._free -= 1
        return True

    def give(self) -> None:
        self.held -= 1
        self._free += 1


SHARED = DescriptorBudget()


@dataclass
class Admission:
    """At most `total` connections held on one socket, `per_peer` of them by one uid,
    each within the shared descriptor budget, and, with a `rate`, at most so many
    a minute of one uid."""

    total: int
    per_peer: int
    budget: DescriptorBudget = field(default_factory=lambda: SHARED)
    rate: RequestRate | None = None
    held: dict[int, int] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return sum(self.held.values())

    def admit(self, uid: int) -> Ticket | str:
        """A place for `uid` (give it back with `Ticket.release`), else why not."""
        mine = self.held.get(uid, 0)
        if mine >= self.per_peer:
            return f"{self.per_peer} connections of this user already"
        if self.count >= self.total:
            return f"{self.total} connections already"
        if self.rate is not None and not self.rate.allow(uid):
            return f"more than {self.rate.per_minute:g} connections a minute of this user"
        if not self.budget.take():
            return f"descriptors kept in reserve ({self.budget.reserve})"
        self.held[uid] = mine + 1
        return Ticket(self, uid)

    def _release(self, uid: int) -> None:
        left = self.held.get(uid, 0) - 1
        if left > 0:
            self.held[uid] = left
        else:
            self.held.pop(uid, None)
        self.budget.give()


class Ticket:
    """One connection's place in an `Admission`; released once, however often asked."""

    def __init__(self, admission: Admission, uid: int) -> None:
        self._admission: Admission | None = admission
        self.uid = uid

    def release(self) -> None:
        if self._admission is not None:
            self._admission._release(self.uid)
            self._admission = None


@dataclass
class RequestRate:
    """A token bucket per uid: `burst` requests at once, then one every
    60/`per_minute` s. Uids with a full bucket are forgotten (bounded memory)."""

    per_minute: float
    burst: int
    clock: Callable[[], float] = time.monotonic
    _buckets: dict[int, tuple[float, float]] = field(default_factory=dict)

    def allow(self, uid: int) -> bool:
        now = self.clock()
        tokens, then = self._buckets.get(uid, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + (now - then) * self.per_minute / 60.0)
        if tokens < 1.0:
            self._buckets[uid] = (tokens, now)
            return False
        self._buckets[uid] = (tokens - 1.0, now)
        if len(self._buckets) > 1024:
            self._forget_full(now)
        return True

    def _forget_full(self, now: float) -> None:
        for uid, (tokens, then) in list(self._buckets.items()):
            if tokens + (now - then) * self.per_minute / 60.0 >= self.burst:
                del self._buckets[uid]
