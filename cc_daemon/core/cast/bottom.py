"""Which sonar bottom a cast is planned on: the freshest confident one of the sources.

Pure. The autopilot's `M` frame carries its sonar's reading; a boat with a
Ping1D wired to the companion computer has a second one (`[sonar]`). This
module picks, among valid readings (`sounding_valid`) at or above the confidence the planner trusts
and no older than `max_age_s`, the one that arrived last, and hands the
planner a start-measuring frame carrying it. With none usable, the frame goes
to the planner as it came (and the planner ignores a bottom it cannot trust).

The `M` frame's reading counts as arriving with the frame: the autopilot does
not say how old its own reading was. It never reads a clock or does I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from cc_daemon.core.protocol import StartMeasuring

AUTOPILOT = "autopilot"
ONBOARD = "onboard"

# No echosounder on a survey boat reads a bottom a kilometre down; a larger
# distance is a sentinel or garbage: 4294967295 (all ones in a u32) is what a
# Ping sends for "no distance". A confidence is a percentage: above 100 it is
# not one. Such a reading is stored as it came and flagged invalid, never
# trusted for a bottom. (0 mm with 0 % is a true report: no echo.)
NO_DISTANCE_MM = 0xFFFFFFFF
MAX_SOUNDING_MM = 1_000_000
MAX_CONFIDENCE_PCT = 100


def sounding_valid(distance_mm: int, confidence_pct: int) -> bool:
    """Whether a (distance, confidence) pair can be a true reading at all."""
    return 0 <= confidence_pct <= MAX_CONFIDENCE_PCT and 0 <= distance_mm < MAX_SOUNDING_MM


@dataclass(frozen=True, slots=True)
class Sounding:
    """A bottom reading from one source, with when it arrived (the caller's clock)."""

    source: str
    distance_mm: int
    confidence_pct: int
    at: float

    @property
    def valid(self) -> bool:
        return sounding_valid(self.distance_mm, self.confidence_pct)


def freshest_bottom(
    soundings: Iterable[Sounding], now: float, *, min_confidence: int, max_age_s: float
) -> Sounding | None:
    """The latest-arriving confident, fresh sounding; None if there is none.

    On a tie the first given wins (give the autopilot's first: it is the
    reading the boat's own plan saw).
    """
    best: Sounding | None = None
    for sounding in soundings:
        if not sounding.valid or sounding.confidence_pct < min_confidence:
            continue
        if not 0 <= now - sounding.at <= max_age_s:
            continue
        if best is None or sounding.at > best.at:
            best = sounding
    return best


def station_for_plan(
    station: StartMeasuring,
    arrived_at: float,
    onboard: Sounding | None,
    *,
    min_confidence: int,
    max_age_s: float,
) -> tuple[StartMeasuring, str | None]:
    """`station` with the sonar fields of the bottom to plan on, and that bottom's source.

    The source is None when no reading is usable: the frame is returned unchanged.
    """
    from_frame = Sounding(
        AUTOPILOT, station.sonar_distance_mm, station.sonar_confidence_pct, arrived_at
    )
    candidates = [from_frame] if onboard is None else [from_frame, onboard]
    best = freshest_bottom(
        candidates, arrived_at, min_confidence=min_confidence, max_age_s=max_age_s
    )
    if best is None:
        return station, None
    if best.source == AUTOPILOT:
        return station, AUTOPILOT
    chosen = StartMeasuring(
        station.timestamp_s,
        station.lon_e7,
        station.lat_e7,
        station.alt_mm,
        best.distance_mm,
        min(best.confidence_pct, 100),
    )
    return chosen, best.source
