"""R-F repeats: an `R-F` that always arrives.

The 2023 firmware sends `M` once, then nothing at all until it reads `R-F`,
and has no timeout: a corrupt `R-F` would strand the boat at the station.
After an `R-F` goes out, if the autopilot stays silent (no frame at all) for
`after_s`, the same `R-F` is due again, up to `repeats` times; any frame from
the autopilot ends the repeats (the firmware resumes `T` once it has read one).

Pure: told when `R-F` went out and when a frame arrived, asked what is due at
`now`. It never sends, sleeps or reads a clock; the shell does.
"""

from __future__ import annotations

from cc_daemon.core.protocol import Finished


class RfRepeater:
    def __init__(self, after_s: float, repeats: int) -> None:
        if after_s <= 0 or repeats < 0:
            raise ValueError("after_s must be > 0 and repeats >= 0")
        self.after_s = after_s
        self.repeats = repeats
        self._frame: Finished | None = None
        self._since = 0.0
        self.sent_again = 0  # repeats of the current R-F

    @property
    def waiting(self) -> bool:
        """An `R-F` is out and unconfirmed, with repeats left."""
        return self._frame is not None

    def sent(self, frame: Finished, now: float) -> None:
        """A new `R-F` went out at `now`: watch for silence after it."""
        self._frame = frame if self.repeats else None
        self._since = now
        self.sent_again = 0

    def frame_received(self) -> None:
        """The autopilot spoke: it is not stuck waiting for this `R-F`."""
        self._frame = None

    def next_deadline(self) -> float | None:
        return None if self._frame is None else self._since + self.after_s

    def due(self, now: float) -> Finished | None:
        """The `R-F` to send again at `now`, if the silence has lasted long enough."""
        frame = self._frame
        if frame is None or now - self._since < self.after_s:
            return None
        self.sent_again += 1
        self._since = now
        if self.sent_again >= self.repeats:
            self._frame = None  # this one is the last
        return frame
