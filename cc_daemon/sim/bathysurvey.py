"""A day of soundings written straight from the simulator's models into a journal.

This module owns a bathymetric survey written without running it in real time:
the boat sails a lines mission (`sim.lines`) at survey speed on a fake clock, the
autopilot's echosounder rides in its `P-T` fixes (`fix_rate_hz`, 2 a second as
the journal keeps them) and the companion computer's own Ping1D journals its
readings (`ping_rate_hz`, 4 a second), both from `sim.ping1d.FieldSounder` with
its errors (`sim.echosounder`), each transducer at its own draft; a GPS glitch
now and then throws a fix far off the track. Stations along the lines are cast
(journaled as the daemon does, without stopping the soundings). Twelve hours
(86,400 fixes and 172,800 readings) are written in well under a minute.

What the journal never says comes back as `SurveyTruth`: what each reading was
(good, a second echo, a shallow return, a dropout), which fixes jumped, and the
bed itself (`mission.field`), for the tests and benchmarks that judge a map. It
drives the journal through its API, as `store.synthetic` does; the daemon never
uses it.
"""

from __future__ import annotations

import random
import time
from dataclasses import dataclass, field

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.sim.echosounder import EchoErrors, EchoKind
from cc_daemon.sim.lines import SURVEY_SPEED_M_S
from cc_daemon.sim.mission import ORIGIN_ALT_M, Mission, Point
from cc_daemon.sim.ping1d import Echo, FieldSounder
from cc_daemon.store.journal import Journal
from cc_daemon.store.synthetic import FakeClock

ONBOARD_PORT = "/dev/ttyPing1D"
GLITCH_M = 60.0  # how far a glitching GPS throws a fix


@dataclass
class SurveyTruth:
    """What the journal does not say, in the order the rows were written."""

    mission: Mission
    fix_kinds: list[EchoKind] = field(default_factory=list)
    ping_kinds: list[EchoKind] = field(default_factory=list)
    jumped: list[bool] = field(default_factory=list)  # per fix: its position a glitch
    casts: int = 0

    @property
    def fixes(self) -> int:
        return len(self.fix_kinds)

    @property
    def pings(self) -> int:
        return len(self.ping_kinds)


class _Track:
    """Where the boat is after `metres` along the whole mission (every leg in turn)."""

    def __init__(self, mission: Mission) -> None:
        self.mission = mission
        self.ends: list[float] = []
        total = 0.0
        for i in range(len(mission.stations)):
            total += mission.leg_length_m(i)
            self.ends.append(total)
        self.length_m = total

    def at(self, metres: float) -> tuple[Point, int]:
        """The point, and the index of the station ahead (len(stations): past the last)."""
        start = 0.0
        for i, end in enumerate(self.ends):
            if metres < end:
                return self.mission.along_leg(i, metres - start), i
            start = end
        return self.mission.stations[-1].point, len(self.ends)


def write_lines_survey(
    journal: Journal,
    clock: FakeClock,
    mission: Mission,
    *,
    duration_s: float | None = None,
    fix_rate_hz: float = 2.0,
    ping_rate_hz: float = 4.0,
    errors: EchoErrors | None = None,
    autopilot_draft_m: float = 0.0,
    onboard_draft_m: float = 0.0,
    glitch_rate: float = 0.0,
    onboard: bool = True,
    seed: int = 1,
    speed_m_s: float = SURVEY_SPEED_M_S,
    max_pending: int = 20_000,
) -> SurveyTruth:
    """Sail `mission` (for `duration_s`, else to its end) into `journal`, advancing `clock`.

    `errors`: both echosounders' (`EchoErrors()` by default). `glitch_rate`: the share
    of fixes a GPS glitch throws `GLITCH_M` off the track. `onboard`: whether the
    companion computer has its own Ping1D. Waits (really) while the journal has
    `max_pending` rows unwritten, so it never overflows the journal's buffer.
    """
    errors = errors or EchoErrors()
    track = _Track(mission)
    here: list[tuple[Point, bool]] = [(mission.start, True)]

    def where() -> tuple[Point, bool]:
        return here[0]

    autopilot = FieldSounder(mission, where, seed=seed, errors=errors, draft_m=autopilot_draft_m)
    ping = FieldSounder(mission, where, seed=seed + 1, errors=errors, draft_m=onboard_draft_m)
    rng = random.Random(seed + 2)
    truth = SurveyTruth(mission)
    end_s = track.length_m / speed_m_s if duration_s is None else duration_s
    step_s = 1.0 / ping_rate_hz
    fix_every = max(1, round(ping_rate_hz / fix_rate_hz))
    journal.record_event("daemon_started", version="bathysurvey")
    station_ahead = 0
    steps = int(end_s / step_s)
    for n in range(steps + 1):
        t_s = n * step_s
        point, ahead = track.at(t_s * speed_m_s)
        here[0] = (point, True)
        while station_ahead < min(ahead, len(mission.stations)):
            _cast(journal, mission, station_ahead, int(t_s), truth)
            station_ahead += 1
        if onboard:
            echo = ping()
            journal.record_sonar(ONBOARD_PORT, echo.distance_mm, echo.confidence_pct)
            truth.ping_kinds.append(ping.last_kind)
        if n % fix_every == 0:
            echo = autopilot()
            jumped = rng.random() < glitch_rate
            shown = Point(point.east_m + GLITCH_M, point.north_m) if jumped else point
            journal.record_fix(Telemetry(int(t_s) % 65536, *_fields(shown, echo)))
            truth.fix_kinds.append(autopilot.last_kind)
            truth.jumped.append(jumped)
        clock.advance(step_s)
        if n % 4000 == 0:
            while (health := journal.health()).writable and health.pending_rows > max_pending:
                time.sleep(0.005)
    if duration_s is None:  # sailed to the end: the last station is there
        while station_ahead < len(mission.stations):
            _cast(journal, mission, station_ahead, int(end_s), truth)
            station_ahead += 1
    journal.record_event("daemon_stopped")
    return truth


def _fields(p: Point, echo: Echo) -> tuple[int, int, int, int, int]:
    lon, lat = p.e7
    return lon, lat, round(ORIGIN_ALT_M * 1000), echo.distance_mm, echo.confidence_pct


def _cast(journal: Journal, mission: Mission, index: int, t_s: int, truth: SurveyTruth) -> None:
    """Station `index`'s cast, journaled as the daemon journals one (no soundings stop)."""
    truth.casts += 1
    truth.fix_kinds.append(EchoKind.GOOD)  # the station's M: a fix with its sounding
    truth.jumped.append(False)
    station = mission.stations[index]
    depth = station.water_depth_m
    echo = Echo(round(depth * 1000), 95)
    message = StartMeasuring(t_s % 65536, *_fields(station.point, echo))
    journal.record_fix(message)
    planned = max(0.0, min(5.0, depth - 0.5))
    cast_id = journal.start_cast(
        message, planned_depth_m=planned, mode="continuous", plan={"target_depth_m": 5.0}
    )
    journal.record_sample(cast_id, planned, "dwelling")
    journal.end_cast(cast_id, outcome="completed", reached_depth_m=planned)
