"""Which sonar bottom a cast is planned on: the freshest trusted one of the sources.

Pure. The autopilot's `M` frame carries its sonar's reading; a boat with a
Ping1D wired to the companion computer has a second one (`[sonar]`). This
module says whether a reading can be trusted at all (`distrust`: a confidence
under the planner's or over 100 %, a distance of 0 or a sentinel such as
4294967295 mm is no bottom), picks among the trusted readings no older than
`max_age_s` the one that arrived last, and hands the planner a start-measuring
frame carrying it. With none usable, the frame goes to the planner as it came
(and the planner, finding no bottom it can trust, casts blind).

The `M` frame's reading counts as arriving with the frame: the autopilot does
not say how old its own reading was. It never reads a clock or does I/O.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from cc_daemon.core.protocol import StartMeasuring

AUTOPILOT = "autopilot"
ONBOARD = "onboard"

NO_ECHO_MM = 0  # what a Ping reports with no echo (and an autopilot with no sonar)
# No echosounder on a survey boat reads a bottom a kilometre down; a larger
# distance is a sentinel or garbage: 4294967295 (all ones in the frame's u32
# field) is what a driver that never had a reading leaves there.
# A reading is stored as it came and flagged invalid when it cannot be one: a
# confidence over 100 %, a distance of a kilometre or more. (0 mm with 0 % is a
# true report: no echo; it is valid, but no bottom to plan on.)
NO_DISTANCE_MM = 0xFFFFFFFF  # what a Ping sends for "no distance"
MAX_SOUNDING_MM = 1_000_000
MAX_CONFIDENCE_PCT = 100


def distrust(distance_mm: int, confidence_pct: int, *, min_confidence: int) -> str | None:
    """Why a sonar reading is no bottom to plan on; None when it can be trusted."""
    if confidence_pct > MAX_CONFIDENCE_PCT:
        return f"sonar confidence {confidence_pct} % is over 100 %: not a reading"
    if distance_mm == NO_ECHO_MM:
        return "sonar distance 0 mm: no echo"
    if distance_mm >= MAX_SOUNDING_MM:
        return f"sonar distance {distance_mm} mm cannot be a bottom"
    if confidence_pct < min_confidence:
        return (
            f"sonar confidence {confidence_pct} % is under cast.min_sonar_confidence "
            f"{min_confidence} %"
        )
    return None


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
    """The latest-arriving trusted (`distrust`), fresh sounding; None if there is none.

    On a tie the first given wins (give the autopilot's first: it is the
    reading the boat's own plan saw).
    """
    best: Sounding | None = None
    for sounding in soundings:
        if not 0 <= now - sounding.at <= max_age_s:
            continue
        if distrust(sounding.distance_mm, sounding.confidence_pct, min_confidence=min_confidence):
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
        best.confidence_pct,  # trusted, so 0-100
    )
    return chosen, best.source
