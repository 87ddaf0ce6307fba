"""A lost `M`: the autopilot may be waiting for an answer we could not read.

The 2023 firmware sends `T` about every 1.1 s, sends `M` once at a station,
then nothing until it reads `R-F`. If `T` frames stop for more than
`silence_s` while corrupt frames arrived since the last `T`, and no cast is
running, the likeliest story is a corrupt `M`: the boat now waits at the
station for ever. Nothing can be sent (we cannot answer an `M` we did not
read); this watch only says so, once per silence, so the shell can log it at
error, journal it and show it in the status.

Pure: told about `T` frames and corrupt frames, asked at `now`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

SILENCE_S = 3.0


@dataclass(frozen=True, slots=True)
class LostStart:
    silent_for_s: float
    corrupt_frames: int  # corrupt frames since the last T


class LostStartWatch:
    def __init__(self, silence_s: float = SILENCE_S) -> None:
        self.silence_s = silence_s
        self._last_t: float | None = None
        self._corrupt = 0
        self.suspected: LostStart | None = None  # set while the silence lasts

    def heard(self, now: float) -> None:
        """The autopilot's state is known at `now`: a `T` or a readable `M`
        arrived, or a cast just ended (the silence starts over)."""
        self._last_t = now
        self._corrupt = 0
        self.suspected = None

    def corrupt(self) -> None:
        self._corrupt += 1

    def next_deadline(self, cast_running: bool) -> float | None:
        """The first `now` at which `check` would suspect a lost `M`, if nothing is
        heard before it; None while nothing could (no corrupt frame, a cast, said)."""
        last = self._last_t
        if self.suspected is not None or last is None or cast_running or not self._corrupt:
            return None
        return math.nextafter(last + self.silence_s, math.inf)  # `check` wants more than

    def check(self, now: float, cast_running: bool) -> LostStart | None:
        """A new suspicion at `now` (once per silence), else None."""
        last = self._last_t
        if self.suspected is not None or last is None or cast_running or not self._corrupt:
            return None
        if now - last <= self.silence_s:
            return None
        self.suspected = LostStart(round(now - last, 1), self._corrupt)
        return self.suspected
