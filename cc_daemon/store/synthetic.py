"""A synthetic survey written through the `Journal` API, on a fake clock.

This module owns a believable, deterministic survey for the benchmark, the
tests and demonstrations of the data commands: a boat running a lawnmower
pattern over a lake bed of known depth, one telemetry fix a second, and a
probe cast every few minutes (soak, descend, dwell, ascend, one sample a
second) with the planning rules of the daemon (target depth, sonar bottom
clearance, skipped when too shallow).

It drives the journal exactly as the daemon does, through `record_fix`,
`start_cast`, `record_sample`, `end_cast` and `record_event`, with a
`FakeClock` so hours of survey are written in seconds. It never touches the
file directly and is never used by the daemon itself.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.store.journal import Journal

METRES_PER_DEG_LAT = 111_320.0
START_WALL_S = 1_717_228_800.0  # 2024-06-01T08:00:00Z
ORIGIN = (40.4506308, -3.7260579)  # lat, lon: the manual's example position

SPEED_M_S = 1.5  # boat speed along a survey line
LEG_M = 1000.0  # length of one line of the lawnmower pattern
SPACING_M = 50.0  # distance between lines
WINCH_M_S = 0.25  # probe line speed
TARGET_DEPTH_M = 5.0
CLEARANCE_M = 0.5
MIN_DEPTH_M = 0.3
MIN_CONFIDENCE = 70
SOAK_S = 5
SOAK_DEPTH_M = 0.5
DWELL_S = 10


class FakeClock:
    """Monotonic and wall clocks that move only when told to."""

    def __init__(self, wall_s: float = START_WALL_S, mono_s: float = 1000.0) -> None:
        self._wall = wall_s
        self._mono = mono_s

    def monotonic(self) -> float:
        return self._mono

    def wall(self) -> float:
        return self._wall

    def advance(self, seconds: float) -> None:
        self._mono += seconds
        self._wall += seconds


@dataclass
class SurveySummary:
    fixes: int = 0
    casts: int = 0
    samples: int = 0
    skipped: int = 0
    events: int = 0


def water_depth_m(east_m: float, north_m: float) -> float:
    """The lake bed: 0.2 m at the shore (south-west corner) to about 12 m, smooth."""
    shore = min(1.0, math.hypot(east_m, north_m) / 60.0)
    ripple = 0.5 + 0.5 * math.sin(east_m / 90.0) * math.cos(north_m / 70.0)
    return 0.2 + shore * (3.0 + 9.0 * ripple)


def boat_position(distance_m: float) -> tuple[float, float]:
    """East and north offsets (m) after `distance_m` along the lawnmower pattern."""
    leg_and_turn = LEG_M + SPACING_M
    leg, along = divmod(distance_m, leg_and_turn)
    if along <= LEG_M:
        east = along if int(leg) % 2 == 0 else LEG_M - along
        return east, leg * SPACING_M
    east = LEG_M if int(leg) % 2 == 0 else 0.0
    return east, leg * SPACING_M + (along - LEG_M)


def _fields(t_s: int, east: float, north: float) -> tuple[int, int, int, int, int, int]:
    """The fields of a `P-T` / `P-M` frame sent at `t_s` from (east, north)."""
    lat = ORIGIN[0] + north / METRES_PER_DEG_LAT
    lon = ORIGIN[1] + east / (METRES_PER_DEG_LAT * math.cos(math.radians(ORIGIN[0])))
    depth = water_depth_m(east, north)
    confidence = 100 if depth > 1.0 else 80  # the Ping is less sure in very shallow water
    return (
        t_s % 65536,
        round(lon * 1e7),
        round(lat * 1e7),
        702_385,
        round(depth * 1000),
        confidence,
    )


def cast_profile(planned_m: float) -> list[tuple[float, str]]:
    """The probe depth and phase each second of a continuous cast to `planned_m`."""
    samples = [(SOAK_DEPTH_M, "soaking")] * SOAK_S
    depth = SOAK_DEPTH_M
    while depth < planned_m:
        depth = min(planned_m, depth + WINCH_M_S)
        samples.append((depth, "descending"))
    samples += [(planned_m, "dwelling")] * DWELL_S
    while depth > 0.0:
        depth = max(0.0, depth - WINCH_M_S)
        samples.append((depth, "ascending"))
    return samples


def write_survey(
    journal: Journal,
    clock: FakeClock,
    *,
    duration_s: float,
    cast_every_s: float = 600.0,
    max_pending: int | None = 20_000,
) -> SurveySummary:
    """Record `duration_s` seconds of survey into `journal`, advancing `clock`.

    One fix a second; every `cast_every_s` the boat stops at a station and the
    probe is cast while fixes keep coming. With `max_pending`, waits (really)
    whenever the journal has that many rows unwritten, so fast-forwarding never
    overflows its buffer.
    """
    summary = SurveySummary()
    journal.record_event("daemon_started", version="synthetic")
    summary.events += 1
    distance = 0.0
    elapsed = 0
    next_cast = 0.0  # the first station is at the shore: too shallow, skipped
    profile: list[tuple[float, str]] = []
    cast_id = 0
    reached = 0.0
    while elapsed < duration_s or profile:  # a cast under way is finished
        east, north = boat_position(distance)
        journal.record_fix(Telemetry(*_fields(elapsed, east, north)))
        summary.fixes += 1
        if not profile and elapsed >= next_cast:
            next_cast += cast_every_s
            station: StartMeasuring = StartMeasuring(*_fields(elapsed, east, north))
            journal.record_fix(station)
            summary.fixes += 1
            planned = TARGET_DEPTH_M
            if station.sonar_confidence_pct >= MIN_CONFIDENCE:
                planned = max(0.0, min(planned, station.sonar_distance_m - CLEARANCE_M))
            plan: dict[str, object] = {"target_depth_m": TARGET_DEPTH_M, "mode": "continuous"}
            cast_id = journal.start_cast(
                station, planned_depth_m=planned, mode="continuous", plan=plan
            )
            summary.casts += 1
            if planned < MIN_DEPTH_M:
                journal.end_cast(
                    cast_id,
                    outcome="skipped-shallow",
                    reached_depth_m=0.0,
                    reason=f"planned depth {planned:.2f} m < {MIN_DEPTH_M} m",
                )
                summary.skipped += 1
            else:
                profile = cast_profile(planned)
                reached = 0.0
        if profile:
            depth, phase = profile.pop(0)
            journal.record_sample(cast_id, depth, phase)
            reached = max(reached, depth)
            summary.samples += 1
            if not profile:
                journal.end_cast(cast_id, outcome="completed", reached_depth_m=reached)
        else:
            distance += SPEED_M_S
        clock.advance(1.0)
        elapsed += 1
        if max_pending is not None and elapsed % 1000 == 0:
            while (health := journal.health()).writable and health.pending_rows > max_pending:
                time.sleep(0.005)
    journal.record_event("daemon_stopped")
    summary.events += 1
    return summary
