"""A lost `M`: the autopilot may be waiting for an answer we could not read.

The 2023 firmware sends `T` about every 1.1 s, sends `M` once at a station,
then nothing at all until it reads `R-F`. If the line falls silent (no frame,
readable or corrupt) for more than `silence_s` after a corrupt frame that
came since the last readable one, and no cast is running, the likeliest story
is that the corrupt frame was the `M`: the boat now waits at the station for
ever. Corrupt frames that keep coming are an autopilot still sending (a noisy
line), not one waiting: the silence is counted from the last frame of any kind.
Nothing can be sent (we cannot answer an `M` we did not read); this watch only
says so, once per silence, so the shell can log it at error, journal it and
show it in the status. A silence while our own serial
port is down is no evidence (the cable, not the autopilot, is quiet): no
suspicion while the link is down, and the silence starts over when it is back.

Pure: told about readable and corrupt frames and the link, asked at `now`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

SILENCE_S = 3.0


@dataclass(frozen=True, slots=True)
class LostStart:
    silent_for_s: float  # since the last frame of any kind
    corrupt_frames: int  # corrupt frames since the last readable one


class LostStartWatch:
    def __init__(self, silence_s: float = SILENCE_S) -> None:
        self.silence_s = silence_s
        self._last_t: float | None = None  # the last readable frame
        self._last_frame: float | None = None  # the last frame, readable or not
        self._corrupt = 0
        self._link_up = True
        self.suspected: LostStart | None = None  # set while the silence lasts

    def heard(self, now: float) -> None:
        """The autopilot's state is known at `now`: a `T` or a readable `M`
        arrived, or a cast just ended (the silence starts over)."""
        self._last_t = now
        self._last_frame = now
        self._corrupt = 0
        self.suspected = None

    def corrupt(self, now: float) -> None:
        self._corrupt += 1
        self._last_frame = now

    def link(self, up: bool, now: float) -> None:
        """Our serial port went down or came back at `now`."""
        self._link_up = up
        if up and self._last_frame is not None:
            self._last_frame = now  # only a silence heard on a working cable counts

    def next_deadline(self, cast_running: bool) -> float | None:
        """The first `now` at which `check` would suspect a lost `M`, if nothing is
        heard before it; None while nothing could (no corrupt frame, a cast, said)."""
        last = self._last_frame
        if self.suspected is not None or self._last_t is None or cast_running or not self._corrupt:
            return None
        if not self._link_up or last is None:
            return None  # the link's coming back says `changed`, and the silence restarts
        return math.nextafter(last + self.silence_s, math.inf)  # `check` wants more than

    def check(self, now: float, cast_running: bool) -> LostStart | None:
        """A new suspicion at `now` (once per silence), else None."""
        last = self._last_frame
        if self.suspected is not None or self._last_t is None or cast_running or not self._corrupt:
            return None
        if not self._link_up or last is None:
            return None
        if now - last <= self.silence_s:
            return None
        self.suspected = LostStart(round(now - last, 1), self._corrupt)
        return self.suspected
