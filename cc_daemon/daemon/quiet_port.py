"""An open port that stays silent: say so soon, then ever less often.

A serial port that opens but never carries a frame (the wrong port, a loose
wire, the autopilot off, a wrong baud rate) looked exactly like a healthy idle
link: nothing in the log for as long as it lasted. From the port's opening
until the first readable frame, this says `nothing heard from the autopilot on
PORT for N s` after `first_s`, then at intervals doubling up to `max_s`; with
only corrupt frames heard it points at the baud rate. Once a frame is read the
link is known to work: a later silence (the firmware waiting at a station) is
the lost-M watch's business, not this one's.

Pure: told about openings and frames, asked at `now`.
"""

from __future__ import annotations

FIRST_S = 5.0
MAX_S = 600.0


class QuietPort:
    def __init__(self, first_s: float = FIRST_S, max_s: float = MAX_S) -> None:
        self.first_s = first_s
        self.max_s = max_s
        self._opened_at: float | None = None  # None: closed, or a frame was read
        self._due = 0.0
        self._interval = first_s
        self._corrupt = 0

    def opened(self, now: float) -> None:
        self._opened_at = now
        self._interval = self.first_s
        self._due = now + self.first_s
        self._corrupt = 0

    def closed(self) -> None:
        self._opened_at = None

    def heard(self) -> None:
        """A readable frame: the wiring and the baud rate are right."""
        self._opened_at = None

    def corrupt(self) -> None:
        self._corrupt += 1

    def next_due(self) -> float | None:
        """When `due` next has something to say (None: a frame was read, or no port)."""
        return None if self._opened_at is None else self._due

    def due(self, now: float, port: str) -> str | None:
        """What to say at `now`, if anything."""
        if self._opened_at is None or now < self._due:
            return None
        self._due = now + min(self._interval * 2, self.max_s)
        self._interval = min(self._interval * 2, self.max_s)
        silent = int(now - self._opened_at)
        if self._corrupt:
            return (
                f"nothing readable from the autopilot on {port} for {silent} s: "
                f"{self._corrupt} corrupt frames (check serial.baudrate and the wiring)"
            )
        return (
            f"nothing heard from the autopilot on {port} for {silent} s "
            "(check the wiring, that the autopilot is on, and serial.port)"
        )
