"""The shape of a simulated run: its pace, its options and the daemon's settings for it.

This module owns what a run is asked to be (`SimOptions`, `AutopilotOnlyOptions`),
how fast the simulated world runs (`Pace`), and how the user's settings become the
daemon's and the autopilot's settings for a run. It is pure: it opens nothing and
never starts a run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from cc_daemon.config.statuspaths import SIMULATOR_JOURNAL
from cc_daemon.sim.autopilot import UCM_2023_FRAME_PERIOD_S, AutopilotConfig, Firmware
from cc_daemon.sim.lines import (
    DEFAULT_LINE_LENGTH_M,
    DEFAULT_LINES,
    DEFAULT_SPACING_M,
    SURVEY_SPEED_M_S,
    make_lines_mission,
)
from cc_daemon.sim.mission import (
    MIN_CASTABLE_WATER_M,
    SHALLOW_WATER_M,
    SONAR_MAX_NOISE_M,
    Mission,
    make_mission,
)

if TYPE_CHECKING:
    from cc_daemon.config import CastSettings, Settings

DEFAULT_DB = SIMULATOR_JOURNAL
PATTERNS = ("stations", "lines")
STALL_AT_M = 1.0  # shallower than every castable station's plan (>= 1.95 m)


@dataclass(frozen=True, slots=True)
class Pace:
    """How fast the simulated world runs. Time itself is never scaled: speeds are."""

    name: str
    frame_period_s: float
    boat_speed_m_s: float
    winch_speed_m_s: float | None  # None keeps the daemon's configured speed
    cast: dict[str, float] = field(default_factory=dict)  # daemon [cast] overrides
    finish_margin_s: float = 60.0  # beyond the daemon's max_duration_s

    def finish_timeout_s(self, max_duration_s: float) -> float:
        """How long the autopilot waits at a station for R-F before giving up."""
        return max_duration_s + self.finish_margin_s


# The demo: the firmware's one frame a second, but brisk transits (a few seconds
# each), a winch at 1.25 m/s and a second and a half at the bottom. A three-station
# survey takes about half a minute.
FAST = Pace(
    "fast",
    frame_period_s=1.0,
    boat_speed_m_s=80.0,
    winch_speed_m_s=1.25,
    cast={"bottom_dwell_s": 1.5, "dwell_s": 1.0, "soak_s": 0.0, "max_duration_s": 20.0},
    finish_margin_s=5.0,
)
# The boat as it is: one frame a second, 1.5 m/s (3 knots), the daemon's own settings.
# `--pace real`; `--realtime` is its older spelling.
REALTIME = Pace("real", frame_period_s=1.0, boat_speed_m_s=1.5, winch_speed_m_s=None)
PACES = {pace.name: pace for pace in (FAST, REALTIME)}


@dataclass(frozen=True, slots=True)
class SimOptions:
    stations: int = 3
    seed: int = 1
    realtime: bool = False
    corrupt: float = 0.0  # probability per byte of a bit flip, both directions
    drop_link_at: float | None = None  # seconds into the run
    drop_link_for: float = 3.0
    winch_stall: bool = False
    winch_fail_home: bool = False
    winch_fault: str = "none"  # the mock drum's sensor fault (--winch gpio-mock)
    resend_m: bool = False  # keep resending M during a cast (a flight plan holding the station)
    db: Path | None = None  # the journal; default ./simulate.db
    log_file: Path | None = None  # the daemon's JSON log lines; default beside the journal
    live: bool | None = None  # None: the rich view when stdout is a terminal
    settings: Settings | None = None  # the daemon's base settings (--config, env, flags)
    out: TextIO | None = None  # default sys.stdout
    handle_signals: bool = True  # Ctrl-C / SIGTERM end the run cleanly
    pace: Pace | None = None  # default FAST, or REALTIME with `realtime`
    sonar: bool = True  # the autopilot reads a Ping1D: simulated on a pty, or at sonar_port
    sonar_port: str | None = None  # a real Ping1D (a bench test of the whole chain)
    firmware: Firmware = "ucm-2023"  # which autopilot firmware to behave as
    # "lines": parallel lines for bathymetry (`sim.lines`), sailed at survey speed
    pattern: str = "stations"
    spacing_m: float = DEFAULT_SPACING_M
    lines: int = DEFAULT_LINES
    line_length_m: float = DEFAULT_LINE_LENGTH_M

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise ValueError(f"--pattern {self.pattern}: one of {', '.join(PATTERNS)}")
        if self.stations < 1:
            raise ValueError(f"--stations {self.stations}: allowed >= 1")
        if not 0.0 <= self.corrupt <= 1.0:
            raise ValueError(f"--corrupt {self.corrupt}: allowed 0..1 (probability per byte)")
        if self.drop_link_at is not None and self.drop_link_at < 0:
            raise ValueError(f"--drop-link-at {self.drop_link_at}: allowed >= 0 (seconds)")
        if self.drop_link_for <= 0:
            raise ValueError(f"--drop-link-for {self.drop_link_for}: allowed > 0 (seconds)")

    def mission(self) -> Mission:
        """The run's mission (ValueError: one that cannot be laid out)."""
        if self.pattern == "lines":
            return make_lines_mission(
                self.stations,
                self.seed,
                spacing_m=self.spacing_m,
                lines=self.lines,
                line_length_m=self.line_length_m,
            )
        return make_mission(self.stations, self.seed)

    @property
    def boat_speed_m_s(self) -> float:
        """Lines are sailed at survey speed whatever the pace: soundings a metre or so
        apart, as a real survey's (the pace shortens the casts)."""
        return SURVEY_SPEED_M_S if self.pattern == "lines" else self.chosen_pace.boat_speed_m_s

    @property
    def chosen_pace(self) -> Pace:
        if self.pace is not None:
            return self.pace
        return REALTIME if self.realtime else FAST

    @property
    def db_path(self) -> Path:
        return self.db if self.db is not None else DEFAULT_DB

    @property
    def log_path(self) -> Path:
        return self.log_file if self.log_file is not None else self.db_path.with_suffix(".log")


@dataclass(frozen=True, slots=True)
class AutopilotOnlyOptions:
    port: str
    baudrate: int = 9600
    stations: int = 3
    seed: int = 1
    frame_period_s: float | None = None  # None: the firmware's own (1.1 s or 1 s)
    boat_speed_m_s: float = 1.5
    resend_m: bool = False
    check_plan: bool = True
    firmware: Firmware = "ucm-2023"
    finish_timeout_s: float = 900.0
    live: bool | None = None
    out: TextIO | None = None
    handle_signals: bool = True


# ---------------------------------------------------------------- settings


def daemon_settings(options: SimOptions, port: Path, status: Path | None = None) -> Settings:
    """The daemon's settings for a run: the base ones, with the run's overrides.
    `status`: where its status socket goes unless the settings name one (default:
    beside the pty)."""
    from cc_daemon.config import Settings

    pace = options.chosen_pace
    base = (options.settings or Settings()).model_dump(mode="python")
    base["serial"]["port"] = str(port)
    gpio = base["winch"]["gpio"]
    if base["winch"]["backend"] == "gpio" and gpio["pin_factory"] == "mock":
        # --winch gpio-mock: the real GPIO winch code on mock pins and a simulated drum.
        if pace.winch_speed_m_s is not None:
            gpio["line_speed_m_s"] = pace.winch_speed_m_s
    else:
        base["winch"]["backend"] = "sim"  # never the boat's real winch from a laptop demo
    sim = base["winch"]["sim"]
    if pace.winch_speed_m_s is not None:
        sim["speed_m_s"] = pace.winch_speed_m_s
    if options.winch_stall:
        sim["stall_at_m"] = STALL_AT_M
    if options.winch_fail_home:
        sim["fail_home"] = True
    sim["drum_fault"] = options.winch_fault
    if options.winch_fault in ("adc-garbage", "encoder-dead"):
        # The current sensor: to read garbage from, or to tell a dead encoder from a jam.
        gpio["adc"] = True
    base["cast"].update(pace.cast)
    base["profile"].update(pace_profile(options))
    base["store"]["path"] = str(options.db_path.absolute())
    if base["status"]["path"] is None:
        # Where `cc-daemon status --db JOURNAL` looks (the runner checks that no other
        # run answers there), else the run's own, beside its pty.
        base["status"]["path"] = str(status if status is not None else port.parent / "status.sock")
    if base["sonde"]["backend"] == "none":  # a simulated survey measures with a simulated sonde
        base["sonde"]["backend"] = "sim"
    return Settings.model_validate(base)


def plan_is_predictable(cast: CastSettings) -> bool:
    """Whether these settings refuse exactly the mission's shoal station.

    The mission is built for the default plan (0.5 m clearance, 0.3 m minimum,
    sonar trusted at >= 70 %); a configuration that plans otherwise makes the
    autopilot's refused-here/cast-there check meaningless, so it is turned off.
    """
    shoal_plan = SHALLOW_WATER_M + SONAR_MAX_NOISE_M - cast.bottom_clearance_m
    deep_plan = min(
        cast.target_depth_m, MIN_CASTABLE_WATER_M - SONAR_MAX_NOISE_M - cast.bottom_clearance_m
    )
    return cast.min_sonar_confidence <= 92 and shoal_plan < cast.min_depth_m <= deep_plan


def _number(value: float) -> str:
    return f"{value:g}"


def pace_profile(options: SimOptions) -> dict[str, Any]:
    """The [profile] a pace that speeds the winch up runs with: its casts are not slowed
    down for the profile (the world is fast, not the sensors), so bins as thick as the
    probe travels between two readings (1.25 m at the fast pace), each of one reading.
    A pace at the winch's own speed keeps the configured [profile]."""
    from cc_daemon.config import Settings

    pace = options.chosen_pace
    if pace.winch_speed_m_s is None:
        return {}
    period = (options.settings or Settings()).sonde.period_s
    travel = min(max(round(pace.winch_speed_m_s * period, 2), 0.01), 5.0)
    return {"bin_m": travel, "min_count": 1, "resolve": []}


def pace_changes(options: SimOptions) -> list[str]:
    """What the run's pace changed in the user's settings, each as `key old -> new`.

    Empty when the pace keeps them (`--pace real`) or they already agree: the
    header says exactly this, so a configuration under test is never silently
    replaced by the demo's.
    """
    from cc_daemon.config import Settings

    pace = options.chosen_pace
    base = options.settings or Settings()
    changes: list[str] = []
    speed = base.winch.sim.speed_m_s
    if pace.winch_speed_m_s is not None and pace.winch_speed_m_s != speed:
        changes.append(f"winch.sim.speed_m_s {_number(speed)} -> {_number(pace.winch_speed_m_s)}")
    current = base.cast.model_dump()
    for key, value in pace.cast.items():
        if current[key] != value:
            changes.append(f"cast.{key} {_number(current[key])} -> {_number(value)}")
    profile = base.profile.model_dump()
    for key, value in pace_profile(options).items():
        mine = list(profile[key]) if isinstance(profile[key], tuple) else profile[key]
        if mine != value:
            changes.append(f"profile.{key} {_shown(profile[key])} -> {_shown(value)}")
    return changes


def _shown(value: object) -> str:
    if isinstance(value, tuple | list):
        return "[" + ", ".join(map(str, value)) + "]"
    return _number(value) if isinstance(value, float | int) else str(value)


def firmware_profile(firmware: Firmware, frame_period_s: float | None) -> dict[str, Any]:
    """The autopilot settings a firmware profile brings: the deployed 2023
    firmware's 1.1 s frame period (scaled with a faster pace's) and one
    scripted stick jog; the manual's 1 s."""
    if firmware == "ucm-2023":
        scale = UCM_2023_FRAME_PERIOD_S
        period = scale if frame_period_s is None else frame_period_s * scale
        return {"firmware": firmware, "frame_period_s": period, "stick_jog": True}
    return {"firmware": firmware, "frame_period_s": frame_period_s or 1.0}


def autopilot_config(options: SimOptions, settings: Settings) -> AutopilotConfig:
    """The simulated autopilot's settings for a run against a daemon with `settings`."""
    pace = options.chosen_pace
    return AutopilotConfig(
        **firmware_profile(options.firmware, pace.frame_period_s),
        boat_speed_m_s=options.boat_speed_m_s,
        resend_m_during_cast=options.resend_m,
        finish_timeout_s=pace.finish_timeout_s(settings.cast.max_duration_s),
        max_line_m=settings.winch.max_line_m,
        check_plan=plan_is_predictable(settings.cast),
        # After a replug the daemon retries its port at most this far apart;
        # silence is excused until then, and a second more to answer.
        outage_grace_s=settings.serial.reconnect_max_s + 1.0,
    )
