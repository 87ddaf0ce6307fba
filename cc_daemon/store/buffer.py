"""The journal's unwritten rows, held in memory between two threads.

This module owns the bound on memory: the rows recorded from the event loop
and not yet committed, in two lists (telemetry fixes, and the urgent rest:
cast rows and events) plus the transaction being written, all under one lock.
Beyond `max_buffered_rows` it sheds the oldest fixes first, then the row kinds
of `shed_order`, oldest first; rows of kinds not listed there (a cast's start
and end) are never dropped. It says when the writer must wake and, on the
writer's thread, waits for rows (`_wait_for_rows`); it never touches SQLite or
files, nor starts a thread.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from cc_daemon.store.failures import RateLimitedLog

LOG_INTERVAL_S = 30.0

# A row is a tuple: its kind, then its values in the order of the matching
# INSERT (tuples are the cheapest thing to build on the loop thread). Kind 0 is
# a telemetry fix, the one kind the buffer knows: fixes are written in bulk,
# after everything else, and shed first.
FIX = 0

Row = tuple[Any, ...]


def shed(rows: list[Row], excess: int, order: tuple[int, ...]) -> tuple[list[Row], int]:
    """Drop `excess` rows, oldest first in `order`; return what is kept and how many went."""
    dropped = 0
    for kind in order:
        if dropped >= excess:
            break
        kept: list[Row] = []
        for row in rows:
            if dropped < excess and row[0] == kind:
                dropped += 1
            else:
                kept.append(row)
        rows = kept
    return rows, dropped


class RowBuffer:
    """Rows waiting for the writer. Every `*_locked` method needs `_lock` held."""

    # Row kinds to sacrifice after the fixes when the buffer is full, in order.
    shed_order: tuple[int, ...] = ()
    # Kinds written in bulk with the fixes (no wake-up of their own), shed with them.
    bulk_kinds: frozenset[int] = frozenset({FIX})

    def __init__(self, max_buffered_rows: int) -> None:
        if max_buffered_rows < 1:
            raise ValueError(f"max_buffered_rows={max_buffered_rows!r}: allowed >= 1")
        self._max_rows = max_buffered_rows
        # Shared between the loop thread and the writer: guarded by _lock. The
        # rows not yet written are in `_urgent` (cast rows and events), `_fixes`
        # and `_in_flight` (taken by the writer for the transaction it is in).
        self._lock = threading.Lock()
        self._urgent: list[Row] = []
        self._fixes: list[Row] = []
        self._in_flight: list[Row] = []
        self._dropped_rows = 0
        self._errors = RateLimitedLog(LOG_INTERVAL_S)

    def _pending_locked(self) -> int:
        return len(self._urgent) + len(self._fixes) + len(self._in_flight)

    def _where(self) -> dict[str, str]:
        """Context for log lines about the buffer (the writer adds its file)."""
        return {}

    def _buffer_row(self, row: Row) -> bool:
        """Add `row`, shedding if over the bound; return whether the writer must be
        woken: for a cast row or an event, and for the first bulk row into an empty
        buffer (the writer sleeps without a deadline while it has nothing to write;
        later bulk rows wait for its flush deadline)."""
        fix: bool = row[0] in self.bulk_kinds
        with self._lock:
            wake = not fix or not (self._fixes or self._in_flight)
            (self._fixes if fix else self._urgent).append(row)
            total = self._pending_locked()
            # One bound over everything unwritten. Shed to 90 % so this runs once
            # per many rows, not per row.
            dropped = (
                self._shed_locked(total - self._max_rows * 9 // 10) if total > self._max_rows else 0
            )
        if dropped:
            self._count_dropped(dropped)
        return wake

    def _wait_for_rows(self, deadline: float, wake: threading.Event, stop: threading.Event) -> None:
        """On the writer's thread, sleep until there is something to write: a cast
        row or an event at once, bulk rows (fixes) at `deadline`; with nothing at
        all, until a row arrives (no tick: an idle daemon's writer never wakes).
        `wake` is set when `_buffer_row` says so, `stop` at close."""
        while not stop.is_set():
            with self._lock:
                urgent, bulk = bool(self._urgent), bool(self._fixes)
            if urgent:
                break
            if not bulk and not self._holds_rows():
                wake.wait()
            else:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                wake.wait(left)
            wake.clear()
        wake.clear()

    def _holds_rows(self) -> bool:
        """Whether the subclass holds a row back that a pass will release (a thinned fix)."""
        return False

    def _shed_locked(self, excess: int) -> int:
        """Drop `excess` rows not being written: the oldest fixes, then `shed_order`."""
        dropped = min(excess, len(self._fixes))
        del self._fixes[:dropped]
        if excess > dropped:
            self._urgent, more = shed(self._urgent, excess - dropped, self.shed_order)
            dropped += more
        return dropped

    def _count_dropped(self, dropped: int) -> None:
        with self._lock:  # both threads drop rows
            self._dropped_rows += dropped
            total = self._dropped_rows
        self._errors.error(
            "dropped",
            "journal buffer full; oldest rows dropped",
            dropped_rows=total,
            max_buffered_rows=self._max_rows,
            **self._where(),
        )

    def _take_chunk_locked(self, size: int, *, urgent: bool) -> list[Row]:
        """The next transaction's rows: the oldest cast rows and events, or fixes."""
        rows = self._urgent if urgent else self._fixes
        chunk = rows[:size]
        del rows[: len(chunk)]
        self._in_flight = chunk
        return chunk

    def _put_back_locked(self, rows: list[Row]) -> int:
        """Return uncommitted rows to the front of their lists; shed if over the bound."""
        self._in_flight = []
        if not rows:
            return 0
        bulk = self.bulk_kinds
        self._urgent[:0] = [row for row in rows if row[0] not in bulk]
        self._fixes[:0] = [row for row in rows if row[0] in bulk]
        excess = len(self._urgent) + len(self._fixes) - self._max_rows
        return self._shed_locked(excess) if excess > 0 else 0
