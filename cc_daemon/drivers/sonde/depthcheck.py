"""The sonde's depth against the winch's line out: disagreement and bottom contact.

Pure (sans-IO), fed on each sonde reading with the time, the line out, the
sonde's pressure depth (None when missing) and whether the winch is paying
out; it returns events for the shell to log, journal and act on. It never reads
a clock, never commands the winch: the cast machine decides what a bottom
contact means (`CastMachine.bottom_contact`).

- `DepthDisagreement` when the two depths differ by more than the threshold
  (the line is slanted by drift, or the probe lies on the bottom), once per
  episode; `DepthAgreement` when they come back within 80 % of it.
- `BottomContact` when, while paying out, the sonde's depth has grown by no
  more than `tolerance_m` for `contact_s` seconds while the line went on
  going out by more than that: the probe is on the bottom (or in weeds, or on
  a slope the sonar did not see). Once per cast; `reset()` between casts.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class DepthDisagreement:
    line_out_m: float
    sonde_depth_m: float


@dataclass(frozen=True, slots=True)
class DepthAgreement:
    line_out_m: float
    sonde_depth_m: float


@dataclass(frozen=True, slots=True)
class BottomContact:
    sonde_depth_m: float
    line_out_m: float
    still_for_s: float


DepthEvent = DepthDisagreement | DepthAgreement | BottomContact

_HYSTERESIS = 0.8


class DepthMonitor:
    def __init__(self, *, disagreement_m: float, contact_s: float, tolerance_m: float) -> None:
        if disagreement_m <= 0 or contact_s <= 0 or tolerance_m <= 0:
            raise ValueError("disagreement_m, contact_s and tolerance_m must be > 0")
        self.disagreement_m = disagreement_m
        self.contact_s = contact_s
        self.tolerance_m = tolerance_m
        self.disagreeing = False
        self.contact: BottomContact | None = None
        # Where the sonde's depth last grew: (time, sonde depth, line out).
        self._anchor: tuple[float, float, float] | None = None

    def reset(self) -> None:
        """A new cast: forget the last one's contact and anchor (not the disagreement)."""
        self.contact = None
        self._anchor = None

    def feed(
        self, now: float, line_out_m: float, sonde_depth_m: float | None, *, paying_out: bool
    ) -> list[DepthEvent]:
        out: list[DepthEvent] = []
        if sonde_depth_m is None:
            return out  # nothing to compare; the anchor waits for the next reading
        gap = abs(sonde_depth_m - line_out_m)
        if not self.disagreeing and gap > self.disagreement_m:
            self.disagreeing = True
            out.append(DepthDisagreement(line_out_m, sonde_depth_m))
        elif self.disagreeing and gap <= self.disagreement_m * _HYSTERESIS:
            self.disagreeing = False
            out.append(DepthAgreement(line_out_m, sonde_depth_m))
        if not paying_out:
            self._anchor = None
            return out
        anchor = self._anchor
        if anchor is None or sonde_depth_m > anchor[1] + self.tolerance_m:
            self._anchor = (now, sonde_depth_m, line_out_m)
            return out
        still_for = now - anchor[0]
        if (
            self.contact is None
            and still_for >= self.contact_s
            and line_out_m - anchor[2] > self.tolerance_m
        ):
            self.contact = BottomContact(sonde_depth_m, line_out_m, still_for)
            out.append(self.contact)
        return out
