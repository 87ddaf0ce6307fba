"""When to say again that a device is still missing, and how to say it.

A serial port that does not exist yet (a USB adapter not plugged in) is waited
for without end; saying so once and then nothing for hours looks like a hang.
`WaitReport` counts the failed attempts and decides, on the times it is given,
when the next "still waiting" line is due: after `first_s`, then at intervals
growing by `factor` up to `max_s` (10 s, 20 s, 40 s ... every 10 minutes), so
a long wait is neither silent nor a flood.

Pure: no clock of its own, no I/O. The link feeds it and logs what it says.
"""

from __future__ import annotations

import time

__all__ = ["WaitReport"]


class WaitReport:
    def __init__(self, first_s: float = 10.0, factor: float = 2.0, max_s: float = 600.0) -> None:
        if not (0 < first_s <= max_s and factor >= 1):
            raise ValueError(f"need 0 < first_s <= max_s and factor >= 1: {first_s, factor, max_s}")
        self.first_s = first_s
        self.factor = factor
        self.max_s = max_s
        self.attempts = 0  # failed attempts since the device was last there
        self.reports = 0
        self.since_wall: float | None = None  # when the first of them failed
        self._interval = first_s
        self._due: float | None = None

    @property
    def waiting(self) -> bool:
        return self.attempts > 0

    def failed(self, monotonic: float, wall: float) -> bool:
        """Count one failed attempt at these times; True if a report is due now."""
        self.attempts += 1
        if self._due is None:
            self.since_wall = wall
            self._due = monotonic + self._interval
            return False  # the first failure is reported with its reason, by the caller
        if monotonic < self._due:
            return False
        self.reports += 1
        self._interval = min(self._interval * self.factor, self.max_s)
        self._due = monotonic + self._interval
        return True

    def message(self, what: str) -> str:
        """`still waiting for /dev/ttyUSB7: 14 attempts since 10:02:11` (local time)."""
        since = time.strftime("%H:%M:%S", time.localtime(self.since_wall or 0.0))
        return f"still waiting for {what}: {self.attempts} attempts since {since}"

    def reset(self) -> None:
        """The device is there: the next wait starts from the beginning."""
        self.attempts = 0
        self.since_wall = None
        self._interval = self.first_s
        self._due = None
