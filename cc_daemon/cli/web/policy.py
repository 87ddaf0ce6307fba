"""What the field page allows a client: its limits, and the headers of every answer.

The figures a hostile client meets (docs/web.md, "Limits"), in one place so the
docs, the tests and the benchmark name the same ones. This module decides
nothing: `listener`, `auth` and `server` apply them.
"""

from __future__ import annotations

from dataclasses import dataclass

# Every answer carries these, errors and aiohttp's own 400s included. Everything
# the page needs comes from itself: no CDN, no inline script. No version in
# `Server`: it would tell a scanner which CVEs to try.
HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
    "Server": "cc-daemon",
}


@dataclass(frozen=True, slots=True)
class Limits:
    """How much of the Pi one client, or all of them, may hold."""

    # Connections open at once. Each is a descriptor and ~20 kB; a phone's
    # browser opens six at most, so 200 is a boat's crew many times over.
    connections: int = 200
    per_client: int = 32  # from one address: one laptop cannot take them all
    # A connection must send a whole request head within this of opening, and
    # the next within `idle_timeout_s` of its last answer, or it is closed: an
    # idle or trickling client holds nothing for long.
    header_timeout_s: float = 10.0
    idle_timeout_s: float = 15.0
    # Descriptors kept free beyond the connections: the journal (file, -wal,
    # -shm, a private copy), the status socket, threads' files, a NetCDF temp.
    reserve_fds: int = 64
    # A download whose client takes nothing for this long is dropped: a reader
    # that stalls must not hold a download's turn (and its thread) for ever.
    send_stall_s: float = 30.0
    # Wrong passwords: `password_burst` at once from one address, then one
    # every `password_refill_s` (a typo or three costs nothing; a guesser gets
    # ten a minute). At most `password_checks_waiting` checks queue for the one
    # scrypt thread; beyond them, 429 at once.
    password_burst: int = 10
    password_refill_s: float = 6.0
    password_checks_waiting: int = 8
