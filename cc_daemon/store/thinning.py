"""At most `rate_hz` telemetry fixes a second into the journal, whatever arrives.

This module owns the rule that bounds what a babbling autopilot can do to the
disk and the memory: time is cut into intervals of 1/`rate_hz` seconds (on the
monotonic clock the rows are stamped with); of the fixes that arrive in one
interval only the latest is kept, and the others are counted. The kept fix is
held until its interval is over (a later fix could still replace it), then
handed on, with its own arrival stamps. The count is handed on too, at most
every `report_every_s`, to be journaled as an event: dropped, never silently.

Pure: rows and times in, rows and counts out. No lock, thread, clock or I/O of
its own; the journal calls it under its buffer lock.
"""

from __future__ import annotations

import math

from cc_daemon.store.buffer import Row

__all__ = ["REPORT_EVERY_S", "FixThinner"]

REPORT_EVERY_S = 60.0


class FixThinner:
    def __init__(self, rate_hz: float, report_every_s: float = REPORT_EVERY_S) -> None:
        self.rate_hz = _checked(rate_hz)
        self.report_every_s = report_every_s
        self.thinned = 0  # fixes dropped since the last report
        self._held: Row | None = None
        self._held_slot = 0
        self._reported_at: float | None = None

    def set_rate(self, rate_hz: float) -> None:
        self.rate_hz = _checked(rate_hz)

    def _slot(self, mono: float) -> int:
        return math.floor(mono * self.rate_hz)

    @property
    def holding(self) -> bool:
        """A fix is held, for `due` to hand on once its interval is over."""
        return self._held is not None

    def offer(self, row: Row, mono: float, replaced: int = 0) -> Row | None:
        """Take a fix stamped `mono`; return the fix of an earlier interval now due, if any.

        `replaced`: fixes stamped the same `mono` just before this one (read together),
        never offered: as if each had been, the newer replaces them and they are counted.
        """
        slot = self._slot(mono)
        held, self._held = self._held, row
        self.thinned += replaced
        if held is not None and slot == self._held_slot:
            self.thinned += 1  # the same interval: the newer fix replaces it
            return None
        self._held_slot = slot
        return held

    def due(self, mono: float) -> Row | None:
        """The held fix, if its interval is over by `mono` (it can no longer be replaced)."""
        if self._held is None or self._slot(mono) == self._held_slot:
            return None
        held, self._held = self._held, None
        return held

    def take(self) -> Row | None:
        """The held fix, whatever the time (the journal is closing)."""
        held, self._held = self._held, None
        return held

    def report(self, mono: float, *, everything: bool = False) -> int:
        """How many fixes to report as dropped now (0: nothing to say yet)."""
        if self._reported_at is None:
            self._reported_at = mono
        if not self.thinned or not (everything or mono - self._reported_at >= self.report_every_s):
            return 0
        count, self.thinned, self._reported_at = self.thinned, 0, mono
        return count


def _checked(rate_hz: float) -> float:
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"telemetry rate must be a positive number of Hz, not {rate_hz!r}")
    return float(rate_hz)


# The in-memory buffer of a thinned journal holds what an hour without a
# writable disk brings at most: telemetry at its rate, depth samples at the
# fastest report period allowed (0.2 s), and room for events. At 2 Hz that is
# 26,200 rows, some 10 MB.
BUFFER_SPAN_S = 3600.0
MAX_SAMPLE_HZ = 5.0
EVENT_ROOM_ROWS = 1000


def buffer_rows(telemetry_rate_hz: float) -> int:
    """Rows to hold in memory for a journal thinned to `telemetry_rate_hz`."""
    return int(BUFFER_SPAN_S * (telemetry_rate_hz + MAX_SAMPLE_HZ)) + EVENT_ROOM_ROWS
