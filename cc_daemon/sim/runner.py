"""`cc-daemon --simulate` and `cc-daemon simulate-autopilot`: the runs and their options.

This module owns wiring the simulator's pieces together and the command-line
options that shape a run:

- `--simulate`: a pty pair in a temporary directory, the real daemon
  (`cc_daemon.service.Daemon`) in this process on the pty's slave symlink, the
  simulated autopilot on the master, the console, and at the end a summary
  read from what the autopilot saw, the daemon's status and its journal. Exit
  status 0 when every station got its `R-F` with no protocol violation.
- `simulate-autopilot --port PATH`: the simulated autopilot alone on a real
  serial port, against a daemon elsewhere (a Raspberry Pi over a USB cable).

It talks to the daemon only through the wire and three public doors: `run()`,
`request_shutdown()` and `snapshot()` (plus the journal file after the run).
It never edits the daemon's state, and leaves nothing behind but the journal
and its log file: the pty pair and the temporary directory are gone when a run
returns, however it ends.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import signal
import sys
import tempfile
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO, cast

from cc_daemon.protocol import Message
from cc_daemon.sim import sondesummary
from cc_daemon.sim.autopilot import (
    Autopilot,
    AutopilotConfig,
    Phase,
    StationLog,
    Violation,
    ViolationKind,
)
from cc_daemon.sim.console import (
    EXIT_PROBE_MAY_BE_DOWN,
    MARKS,
    SimConsole,
    StationRow,
    Summary,
    ViewState,
)
from cc_daemon.sim.mission import (
    EARTH_RADIUS_M,
    MIN_CASTABLE_WATER_M,
    ORIGIN_LAT_DEG,
    ORIGIN_LON_DEG,
    SHALLOW_WATER_M,
    SONAR_MAX_NOISE_M,
    Mission,
    Point,
    make_mission,
)
from cc_daemon.sim.noise import BitFlipper
from cc_daemon.sim.port import FramePort, Received
from cc_daemon.sim.pty import PtyPair

if TYPE_CHECKING:
    from cc_daemon.config import CastSettings, Settings
    from cc_daemon.service import Daemon, DaemonStatus

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2

DEFAULT_DB = Path("simulate.db")
STALL_AT_M = 1.0  # shallower than every castable station's plan (>= 1.95 m)
READY_TIMEOUT_S = 10.0
LINGER_S = 1.0  # after the last station, listen for stray frames this long
_MATCH_RADIUS_M = 15.0  # a journal cast belongs to the station within this distance


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
REALTIME = Pace("realtime", frame_period_s=1.0, boat_speed_m_s=1.5, winch_speed_m_s=None)


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
    resend_m: bool = False  # keep resending M during a cast (a flight plan holding the station)
    db: Path | None = None  # the journal; default ./simulate.db
    log_file: Path | None = None  # the daemon's JSON log lines; default beside the journal
    live: bool | None = None  # None: the rich view when stdout is a terminal
    settings: Settings | None = None  # the daemon's base settings (--config, env, flags)
    out: TextIO | None = None  # default sys.stdout
    handle_signals: bool = True  # Ctrl-C / SIGTERM end the run cleanly
    pace: Pace | None = None  # default FAST, or REALTIME with `realtime`

    def __post_init__(self) -> None:
        if self.stations < 1:
            raise ValueError(f"--stations {self.stations}: allowed >= 1")
        if not 0.0 <= self.corrupt <= 1.0:
            raise ValueError(f"--corrupt {self.corrupt}: allowed 0..1 (probability per byte)")
        if self.drop_link_at is not None and self.drop_link_at < 0:
            raise ValueError(f"--drop-link-at {self.drop_link_at}: allowed >= 0 (seconds)")
        if self.drop_link_for <= 0:
            raise ValueError(f"--drop-link-for {self.drop_link_for}: allowed > 0 (seconds)")

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


# ---------------------------------------------------------------- settings


def daemon_settings(options: SimOptions, port: Path) -> Settings:
    """The daemon's settings for a run: the base ones, with the run's overrides."""
    from cc_daemon.config import Settings

    pace = options.chosen_pace
    base = (options.settings or Settings()).model_dump(mode="python")
    base["serial"]["port"] = str(port)
    base["winch"]["backend"] = "sim"
    sim = base["winch"]["sim"]
    if pace.winch_speed_m_s is not None:
        sim["speed_m_s"] = pace.winch_speed_m_s
    if options.winch_stall:
        sim["stall_at_m"] = STALL_AT_M
    if options.winch_fail_home:
        sim["fail_home"] = True
    base["cast"].update(pace.cast)
    base["store"]["path"] = str(options.db_path.absolute())
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


# ---------------------------------------------------------------- the daemon's log


class LogTap:
    """The daemon's log stream: every line to the log file; info and up queued for the console.

    It is written from inside the daemon's logging calls, so it never raises
    and never prints: a failing log file is counted (`write_errors`) and the
    events for the console wait in a queue until the run's loop `drain`s them.
    A plain object with `write` and `flush` (all structlog needs), not an
    `io` stream: it has no finaliser to flush a file closed before it.
    """

    _QUIET = frozenset({"timestamp", "level", "logger", "event"})
    _SHOWN = frozenset({"info", "warning", "error", "critical"})

    def __init__(self, file: TextIO, clock: Callable[[], float]) -> None:
        self._file = file
        self._clock = clock
        self._partial = ""
        self._events: deque[tuple[float, dict[str, Any]]] = deque()
        self.write_errors = 0

    def write(self, text: str) -> int:
        try:
            self._file.write(text)
        except Exception:  # a full disk, a closed file: the daemon must carry on
            self.write_errors += 1
        try:
            self._partial += text
            *lines, self._partial = self._partial.split("\n")
            for line in lines:
                self._take(line)
        except Exception:  # never into the daemon's logging call
            self._partial = ""
        return len(text)

    def _take(self, line: str) -> None:
        try:
            event = json.loads(line)
        except ValueError:
            return
        if isinstance(event, dict) and event.get("level") in self._SHOWN:
            self._events.append((self._clock(), event))

    def flush(self) -> None:
        try:
            self._file.flush()
        except Exception:
            self.write_errors += 1

    def drain(self) -> list[tuple[float, dict[str, Any]]]:
        """The queued events (time from `clock`, the event), oldest first; the queue empties."""
        out: list[tuple[float, dict[str, Any]]] = []
        while self._events:
            out.append(self._events.popleft())
        return out

    @classmethod
    def describe(cls, event: dict[str, Any]) -> str:
        details = " ".join(f"{k}={v}" for k, v in event.items() if k not in cls._QUIET)
        level = event.get("level", "info")
        prefix = "daemon" if level == "info" else f"daemon {str(level).upper()}"
        return f"{prefix}: {event.get('event', '')}" + (f"  {details}" if details else "")


# ---------------------------------------------------------------- the run


class _Run:
    """One run's moving parts and the loop that moves frames between them."""

    def __init__(
        self,
        mission: Mission,
        autopilot: Autopilot,
        console: SimConsole,
        *,
        daemon: Daemon | None = None,
        pair: PtyPair | None = None,
        flip_out: BitFlipper | None = None,
        flip_in: BitFlipper | None = None,
        drop_at: float | None = None,
        drop_for: float = 3.0,
    ) -> None:
        self.mission = mission
        self.autopilot = autopilot
        self.console = console
        self.daemon = daemon
        self.pair = pair
        self.flip_out = flip_out
        self.flip_in = flip_in
        self.drop_at = drop_at
        self.drop_for = drop_for
        self.tap: LogTap | None = None  # the daemon's log events, for the console
        self.port: FramePort | None = None
        self.ports: list[FramePort] = []
        self.t0 = time.monotonic()
        self.wall0 = time.time()
        self.interrupts = 0
        self.link_drops = 0
        self.unplugged_at: float | None = None
        self.frames_lost = 0  # polled while the cable was out
        self.plans: dict[int, float] = {}  # station number -> planned depth (daemon snapshot)
        self.faults: dict[int, str] = {}  # station number -> winch fault (daemon snapshot)
        self.status: DaemonStatus | None = None
        self._errors_seen = 0
        self._violations_seen = 0
        self._flips_seen = {True: 0, False: 0}  # inbound? -> flips passed to the autopilot
        self._phase = autopilot.phase
        self._index = autopilot.index
        self._link_up = False

    # ------------------------------------------------------------ time and ports

    def now(self) -> float:
        return time.monotonic() - self.t0

    def attach(self, port: FramePort) -> None:
        self.port = port
        self.ports.append(port)
        self._errors_seen = 0

    async def attach_pty(self) -> None:
        assert self.pair is not None
        self.attach(
            await FramePort.over_fd(
                self.pair.master_fd, tx_filter=self.flip_out, rx_filter=self.flip_in
            )
        )

    # ------------------------------------------------------------ the loop

    async def pump(self, done: Callable[[], bool], *, deadline: float | None = None) -> None:
        """Move frames until `done()` (or `deadline`, seconds into the run)."""
        while not done() and (deadline is None or self.now() < deadline):
            self.drain_log()
            now = self.now()
            await self._link_schedule(now)
            self._forward_noise()
            for message in self.autopilot.poll(now):
                await self._send(now, message)
            self._observe(now)
            wait = min(max(self.autopilot.next_deadline - self.now(), 0.0), 0.1)
            port = self.port
            if port is None or port.hung_up:
                await asyncio.sleep(wait)
                continue
            received = await port.receive(wait)
            self.drain_log()  # what the daemon logged before it sent this frame comes first
            self._forward_noise()
            self._on_errors(port)  # found before this frame was handed over, or with it
            if received is not None:
                self._on_received(received)

    async def collect(self, quiet_s: float = 0.2) -> None:
        """Take the frames still on their way, sending none, until `quiet_s` without one."""
        port = self.port
        if port is None:
            return
        while (received := await port.receive(quiet_s)) is not None:
            self.drain_log()
            self._forward_noise()
            self._on_errors(port)
            self._on_received(received)
        self._on_errors(port)
        self.drain_log()

    def drain_log(self) -> None:
        """Show the daemon's queued log events."""
        if self.tap is None:
            return
        for at, event in self.tap.drain():
            self.console.event(at, LogTap.describe(event))

    def _forward_noise(self) -> None:
        """Tell the autopilot when injected noise flipped bits, each way."""
        for flipper, inbound in ((self.flip_in, True), (self.flip_out, False)):
            if flipper is None:
                continue
            times = flipper.flip_times
            for at in times[self._flips_seen[inbound] :]:
                self.autopilot.bits_flipped(at - self.t0, inbound=inbound)
            self._flips_seen[inbound] = len(times)

    async def _send(self, now: float, message: Message) -> None:
        self.console.frame_out(now, message)
        if self.port is None:
            self.frames_lost += 1  # the firmware writes into a dead UART
            return
        try:
            await self.port.send(message)
        except OSError as exc:
            self.console.event(now, f"write failed: {exc}")

    def _on_received(self, received: Received) -> None:
        at = received.time - self.t0
        self.console.frame_in(at, received.message)
        self.autopilot.on_frame(at, received.message)

    def _on_errors(self, port: FramePort) -> None:
        for error, found in zip(
            port.errors[self._errors_seen :], port.error_times[self._errors_seen :], strict=True
        ):
            at = found - self.t0
            self.console.corrupt_in(at, error)
            self.autopilot.on_corrupt(at, error)
        self._errors_seen = len(port.errors)

    async def _link_schedule(self, now: float) -> None:
        if self.pair is None or self.drop_at is None:
            return
        if self.unplugged_at is None and self.link_drops == 0 and now >= self.drop_at:
            if self.port is not None:
                self.port.detach()
                self.port = None
            self.pair.unplug()
            self.unplugged_at = now
            self.link_drops += 1
            self.autopilot.link_down(now)
            self.console.event(now, f"cable pulled for {self.drop_for:g} s")
        elif self.unplugged_at is not None and now >= self.unplugged_at + self.drop_for:
            self.pair.replug()
            await self.attach_pty()
            self.unplugged_at = None
            self.autopilot.link_up(now)
            self.console.event(now, "cable plugged back in: the daemon must reopen the port")

    # ------------------------------------------------------------ watching

    def _observe(self, now: float) -> None:
        ap = self.autopilot
        if ap.phase is not self._phase or ap.index != self._index:
            self._narrate(now)
            self._phase, self._index = ap.phase, ap.index
        for violation in ap.violations[self._violations_seen :]:
            self.console.event(
                now,
                ("excused " if violation.excused else "VIOLATION ")
                + str(violation.kind)
                + f": {violation.detail}",
            )
        self._violations_seen = len(ap.violations)
        status = self.daemon.snapshot() if self.daemon is not None else None
        self.status = status or self.status
        station = ap.station
        if status is not None and station is not None:
            at_station = ap.phase in (Phase.REQUESTING, Phase.CASTING)
            if at_station and status.planned_depth_m is not None:
                self.plans[station.number] = status.planned_depth_m
            if at_station and status.winch_fault:
                self.faults[station.number] = status.winch_fault
            if status.link_up != self._link_up:
                self._link_up = status.link_up
                self.console.event(
                    now, "daemon: port open" if status.link_up else "daemon: port lost"
                )
        self.console.update(self._view(now, status))

    def _narrate(self, now: float) -> None:
        ap = self.autopilot
        old_log = ap.logs[self._index]
        was_at_station = self._phase in (Phase.REQUESTING, Phase.CASTING)
        if was_at_station and old_log.finished_at is not None:
            self.console.event(
                now,
                f"{old_log.station.name}: R-F, leaving; {old_log.reports} depth reports, "
                f"deepest {old_log.max_depth_m:.2f} m",
            )
        station = ap.station
        if station is None:
            if ap.phase is Phase.DONE:
                self.console.event(now, "survey over")
            return
        if ap.phase is Phase.CRUISING:
            begin, end = self.mission.leg(ap.index)
            self.console.event(
                now,
                f"under way to {station.name}: {begin.distance_to(end):.0f} m "
                f"at {ap.config.boat_speed_m_s:g} m/s",
            )
        elif ap.phase is Phase.REQUESTING:
            self.console.event(
                now,
                f"{station.name}: on station in {station.water_depth_m:.2f} m of water; "
                "sending M until R-O",
            )
        elif ap.phase is Phase.CASTING:
            self.console.event(now, f"{station.name}: R-O, the daemon has the station")

    def _view(self, now: float, status: DaemonStatus | None) -> ViewState:
        ap = self.autopilot
        station = ap.station
        at_station = ap.phase in (Phase.REQUESTING, Phase.CASTING)
        lat, lon = ap.position(now).lat_lon
        problems = len(ap.problems)
        return ViewState(
            elapsed_s=now,
            station_number=None if station is None else station.number,
            stations_done=sum(1 for log in ap.logs if log.finished_at is not None),
            station_count=len(ap.logs),
            autopilot_phase=str(ap.phase),
            water_depth_m=station.water_depth_m if (station and at_station) else None,
            probe_depth_m=status.probe_depth_m if status else ap.probe_depth_m,
            planned_depth_m=(
                status.planned_depth_m
                if status and status.planned_depth_m is not None
                else (self.plans.get(station.number) if station and at_station else None)
            ),
            daemon_phase=status.phase if status else "remote",
            daemon_link_up=status.link_up if status else self.port is not None,
            cable_plugged=self.unplugged_at is None,
            frames_out=sum(len(p.sent) for p in self.ports),
            frames_in=sum(len(p.received) for p in self.ports),
            corrupt_in=sum(len(p.errors) for p in self.ports),
            corrupt_at_daemon=status.corrupt_frames if status else 0,
            problems=problems,
            excused=len(ap.violations) - problems,
            lat_deg=lat,
            lon_deg=lon,
            progress=[(log.station.name, self._mark(log)) for log in ap.logs],
        )

    def _mark(self, log: StationLog) -> str:
        if log.finished_at is None:
            current = self.autopilot.station is log.station
            return MARKS["current"] if current else MARKS["pending"]
        if log.problems:
            return MARKS["failed"]
        return MARKS["measured"] if log.reports else MARKS["skipped"]

    # ------------------------------------------------------------ signals

    def on_signal(self) -> None:
        self.interrupts += 1
        now = self.now()
        if self.daemon is None:
            self.console.event(now, "interrupted")
            return
        if self.interrupts == 1:
            self.console.event(now, "Ctrl-C: the daemon brings the probe home, then stops")
            self.daemon.request_shutdown()
        else:
            self.console.event(now, "second Ctrl-C: the daemon stops at once")
            self.daemon.request_shutdown(immediate=True)

    async def close(self) -> None:
        for port in self.ports:
            await port.close()
        self.port = None


# ---------------------------------------------------------------- summaries


def _local(lat_deg: float, lon_deg: float) -> Point:
    north = math.radians(lat_deg - ORIGIN_LAT_DEG) * EARTH_RADIUS_M
    east = (
        math.radians(lon_deg - ORIGIN_LON_DEG)
        * EARTH_RADIUS_M
        * math.cos(math.radians(ORIGIN_LAT_DEG))
    )
    return Point(east, north)


@dataclass(frozen=True, slots=True)
class JournalCast:
    """What the summary needs from one journal cast record."""

    station: int
    planned_depth_m: float
    reached_depth_m: float | None
    outcome: str | None
    reason: str | None


def journal_casts(db: Path, mission: Mission, since_wall_s: float) -> list[JournalCast]:
    """This run's casts in the journal, each matched to its station by position."""
    from cc_daemon.store import JournalReader

    found: list[JournalCast] = []
    with JournalReader(db) as reader:
        for record in reader.casts(since=since_wall_s):
            here = _local(record.lat_deg, record.lon_deg)
            nearest = min(mission.stations, key=lambda s: s.point.distance_to(here))
            if nearest.point.distance_to(here) <= _MATCH_RADIUS_M:
                found.append(
                    JournalCast(
                        nearest.number,
                        record.planned_depth_m,
                        record.reached_depth_m,
                        record.outcome,
                        record.reason,
                    )
                )
    return found


def build_summary(
    run: _Run,
    *,
    casts: list[JournalCast] | None,
    daemon_exit: int | None,
    db_path: Path | None,
    log_path: Path | None,
    notes: list[str] | None = None,
) -> Summary:
    ap = run.autopilot
    now = run.now()
    violations = list(ap.violations)
    by_station: dict[int, list[JournalCast]] = {}
    for recorded_cast in casts or []:
        by_station.setdefault(recorded_cast.station, []).append(recorded_cast)
    rows: list[StationRow] = []
    extra_notes: list[str] = []
    for log in ap.logs:
        number = log.station.number
        recorded = by_station.get(number, [])
        if len(recorded) > 1:
            violations.append(
                Violation(
                    now,
                    ViolationKind.DUPLICATE_CAST,
                    f"the journal holds {len(recorded)} casts for one station",
                    number,
                )
            )
        planned = recorded[-1].planned_depth_m if recorded else run.plans.get(number)
        verdict = log.verdict
        ok = not log.problems and log.finished_at is not None
        outcome = recorded[-1].outcome if recorded else None
        if ok and outcome == "aborted":
            reason = recorded[-1].reason or "no reason given"
            verdict = f"aborted: {reason.removeprefix('winch fault: ')}"
        elif ok and number in run.faults and log.reports:
            verdict = f"aborted: {run.faults[number]}"
        # How deep the probe went: the daemon's journal knows (its winch); the
        # deepest R-M that arrived can fall short (a lost report, a stall
        # between two reports, a cable pulled mid-cast).
        heard = log.max_depth_m if log.reports else (0.0 if log.finished_at is not None else None)
        journal_reached = recorded[-1].reached_depth_m if recorded else None
        reached = journal_reached if journal_reached is not None else heard
        if journal_reached is not None and abs(journal_reached - log.max_depth_m) > 0.05:
            said = (
                f"the deepest R-M that arrived said {log.max_depth_m:.2f} m"
                if log.reports
                else "no R-M arrived"
            )
            extra_notes.append(
                f"S{number}: the journal says the probe reached {journal_reached:.2f} m; {said}"
            )
        if len(recorded) > 1:
            ok = False
            verdict = f"FAILED: {len(recorded)} casts"
        lat, lon = log.station.point.lat_lon
        rows.append(
            StationRow(
                number=number,
                lat_deg=lat,
                lon_deg=lon,
                water_depth_m=log.station.water_depth_m,
                planned_depth_m=planned,
                reached_depth_m=reached,
                duration_s=log.cast_duration_s,
                reports=log.reports,
                verdict=verdict,
                ok=ok,
            )
        )
    if run.drop_at is not None and run.link_drops == 0:
        extra_notes.append(
            f"cable never pulled: the run ended at {now:.1f} s, "
            f"before --drop-link-at {run.drop_at:g}"
        )
    elif run.unplugged_at is not None:
        extra_notes.append(
            f"the run ended with the cable still out (pulled at {run.unplugged_at:.1f} s)"
        )
    status = run.status
    # Where the probe ended: the daemon's winch here, or what a remote daemon last said.
    probe_depth_m = status.probe_depth_m if status is not None else None
    if run.daemon is None:
        probe_depth_m = ap.probe_depth_m
    problems = [v for v in violations if not v.excused]
    if daemon_exit == EXIT_PROBE_MAY_BE_DOWN:
        code = EXIT_PROBE_MAY_BE_DOWN
    elif problems or not ap.survey_complete or run.interrupts or daemon_exit not in (None, 0):
        code = EXIT_FAILED
    else:
        code = EXIT_OK
    return Summary(
        seed=run.mission.seed,
        elapsed_s=now,
        stations=rows,
        frames_to_daemon=sum(len(p.sent) for p in run.ports),
        frames_from_daemon=sum(len(p.received) for p in run.ports),
        corrupt_from_daemon=sum(len(p.errors) for p in run.ports),
        corrupt_at_daemon=status.corrupt_frames if status else None,
        bits_flipped_out=run.flip_out.bits_flipped if run.flip_out else 0,
        bits_flipped_in=run.flip_in.bits_flipped if run.flip_in else 0,
        m_sent=sum(log.m_sent for log in ap.logs),
        link_drops=run.link_drops,
        daemon_port_losses=status.port_losses if status else None,
        casts_completed=status.casts_completed if status else None,
        casts_aborted=status.casts_aborted if status else None,
        casts_skipped=status.casts_skipped if status else None,
        violations=violations,
        db_path=db_path,
        log_path=log_path,
        exit_code=code,
        interrupted=run.interrupts > 0,
        notes=[*(notes or []), *extra_notes],
        daemon_exit=daemon_exit,
        probe_depth_m=probe_depth_m,
        remote=run.daemon is None,
    )


# ---------------------------------------------------------------- --simulate


def autopilot_config(options: SimOptions, settings: Settings) -> AutopilotConfig:
    """The simulated autopilot's settings for a run against a daemon with `settings`."""
    pace = options.chosen_pace
    return AutopilotConfig(
        frame_period_s=pace.frame_period_s,
        boat_speed_m_s=pace.boat_speed_m_s,
        resend_m_during_cast=options.resend_m,
        finish_timeout_s=pace.finish_timeout_s(settings.cast.max_duration_s),
        max_line_m=settings.winch.max_line_m,
        check_plan=plan_is_predictable(settings.cast),
        # After a replug the daemon retries its port at most this far apart;
        # silence is excused until then, and a second more to answer.
        outage_grace_s=settings.serial.reconnect_max_s + 1.0,
    )


def _headline(options: SimOptions, mission: Mission) -> str:
    pace = options.chosen_pace
    extras = [
        f"--corrupt {options.corrupt:g}" if options.corrupt else "",
        f"--drop-link-at {options.drop_link_at:g}" if options.drop_link_at is not None else "",
        "--winch-stall" if options.winch_stall else "",
        "--winch-fail-home" if options.winch_fail_home else "",
        "--resend-m" if options.resend_m else "",
    ]
    noise = " ".join(e for e in extras if e)
    return (
        f"cc-daemon --simulate: {len(mission.stations)} stations, seed {mission.seed}, "
        f"{pace.name} pace, {mission.total_distance_m:.0f} m of transits"
        + (f"  [{noise}]" if noise else "")
    )


@contextlib.contextmanager
def _signals(run: _Run, enabled: bool) -> Iterator[None]:
    loop = asyncio.get_running_loop()
    installed: list[signal.Signals] = []
    if enabled:
        for signum in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(signum, run.on_signal)
            except (ValueError, RuntimeError, NotImplementedError):  # not the main thread
                continue
            installed.append(signum)
    try:
        yield
    finally:
        for signum in installed:
            loop.remove_signal_handler(signum)


async def run_simulation(options: SimOptions) -> int:
    """A whole survey: the daemon in this process against the simulated autopilot."""
    from cc_daemon.logsetup import configure_logging, reset_logging
    from cc_daemon.service import Daemon
    from cc_daemon.store import StoreError

    mission = make_mission(options.stations, options.seed)
    console = SimConsole(options.out, live=options.live)
    flip_out = BitFlipper(options.corrupt, options.seed * 2 + 1) if options.corrupt else None
    flip_in = BitFlipper(options.corrupt, options.seed * 2 + 2) if options.corrupt else None
    db_path = options.db_path.absolute()
    log_path = options.log_path.absolute()
    db_path.parent.mkdir(parents=True, exist_ok=True)
    notes: list[str] = []

    with (
        tempfile.TemporaryDirectory(prefix="cc-daemon-sim-") as tmp,
        PtyPair(Path(tmp) / "ttyAUTOPILOT") as pair,
        log_path.open("a", encoding="utf-8") as log_file,
    ):
        settings = daemon_settings(options, pair.path)
        autopilot = Autopilot(mission, autopilot_config(options, settings))
        daemon = Daemon(settings)
        run = _Run(
            mission,
            autopilot,
            console,
            daemon=daemon,
            pair=pair,
            flip_out=flip_out,
            flip_in=flip_in,
            drop_at=options.drop_link_at,
            drop_for=options.drop_link_for,
        )
        run.tap = LogTap(log_file, run.now)
        configure_logging("json", settings.log.level, stream=cast(TextIO, run.tap))
        console.start(mission, _headline(options, mission))
        daemon_task = asyncio.create_task(daemon.run(), name="daemon")
        daemon_exit: int | None = None
        try:
            with _signals(run, options.handle_signals):
                daemon_exit = await _survey(run, daemon, daemon_task, settings, notes)
        finally:
            try:
                # Something went wrong in the run itself: still bring the probe
                # home if the daemon can, and only then stop it at once.
                await _stop_daemon(daemon, daemon_task, settings)
            finally:
                run.drain_log()
                await run.close()
                console.stop()
                reset_logging()
        casts: list[JournalCast] | None = None
        try:
            casts = journal_casts(db_path, mission, run.wall0 - 1.0)
            notes.extend(sondesummary.sonde_lines(db_path, run.wall0 - 1.0))
        except StoreError as exc:
            notes.append(f"could not read the journal: {exc}")
        summary = build_summary(
            run,
            casts=casts,
            daemon_exit=daemon_exit,
            db_path=db_path,
            log_path=log_path,
            notes=notes,
        )
    console.print_summary(summary)
    return summary.exit_code


async def _survey(
    run: _Run, daemon: Daemon, daemon_task: asyncio.Task[int], settings: Settings, notes: list[str]
) -> int | None:
    """Sail the mission against the running daemon, then stop it; its exit status."""
    autopilot = run.autopilot
    problem = await _wait_ready(daemon, daemon_task)
    if problem is None:
        await run.attach_pty()
        run.t0 = time.monotonic()
        run.wall0 = time.time()
        await run.pump(
            lambda: autopilot.phase is Phase.DONE or run.interrupts > 0 or daemon_task.done()
        )
        if not run.interrupts and not daemon_task.done():
            await run.pump(lambda: run.interrupts > 0, deadline=run.now() + LINGER_S)
    else:
        notes.append(problem)
    daemon.request_shutdown()
    gave_up = autopilot.phase is Phase.DONE and not autopilot.survey_complete
    grace = _shutdown_grace_s(settings, gave_up=gave_up)
    await run.pump(daemon_task.done, deadline=run.now() + grace)
    if not daemon_task.done():
        notes.append(
            f"the daemon did not stop within {grace:.0f} s of the request: stopped at once"
        )
        daemon.request_shutdown(immediate=True)
    try:
        code = await daemon_task
    except Exception as exc:  # a daemon bug: report it in the summary, do not hide it
        notes.append(f"the daemon failed: {type(exc).__name__}: {exc}")
        code = EXIT_FAILED
    await run.collect()  # its last frames (an R-F) may still be on the wire
    run.status = daemon.snapshot()
    autopilot.finish(run.now(), interrupted=run.interrupts > 0)
    return code


async def _stop_daemon(daemon: Daemon, task: asyncio.Task[int], settings: Settings) -> None:
    """Make sure the daemon has stopped: gracefully within the grace, else at once."""
    if task.done():
        return
    daemon.request_shutdown()
    await asyncio.wait({task}, timeout=_shutdown_grace_s(settings, gave_up=False))
    if not task.done():
        daemon.request_shutdown(immediate=True)
        await asyncio.wait({task}, timeout=10.0)
    if task.done() and not task.cancelled():
        task.exception()  # seen: the error that brought us here is the one to report


def _shutdown_grace_s(settings: Settings, *, gave_up: bool) -> float:
    """How long a graceful stop may take: a whole line's haul home, or a moment if
    the autopilot already gave up waiting for R-F (a stranded probe stays down)."""
    if gave_up:
        return 5.0
    return settings.winch.max_line_m / settings.winch.sim.speed_m_s + 10.0


async def _wait_ready(daemon: Daemon, task: asyncio.Task[int]) -> str | None:
    """None once the daemon has its port open; otherwise what went wrong."""
    ready = asyncio.create_task(daemon.ready.wait(), name="daemon-ready")
    try:
        done, _ = await asyncio.wait(
            {ready, task}, timeout=READY_TIMEOUT_S, return_when="FIRST_COMPLETED"
        )
    finally:
        ready.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await ready
    if task in done:
        return "the daemon stopped before it opened its port"
    if not daemon.ready.is_set():
        return f"the daemon did not open its port within {READY_TIMEOUT_S:g} s"
    return None


# ---------------------------------------------------------------- simulate-autopilot


@dataclass(frozen=True, slots=True)
class AutopilotOnlyOptions:
    port: str
    baudrate: int = 9600
    stations: int = 3
    seed: int = 1
    frame_period_s: float = 1.0
    boat_speed_m_s: float = 1.5
    resend_m: bool = False
    check_plan: bool = True
    finish_timeout_s: float = 900.0
    live: bool | None = None
    out: TextIO | None = None
    handle_signals: bool = True


async def run_autopilot(options: AutopilotOnlyOptions) -> int:
    """The simulated autopilot alone on a serial port, against a daemon elsewhere."""
    mission = make_mission(options.stations, options.seed)
    console = SimConsole(options.out, live=options.live)
    config = AutopilotConfig(
        frame_period_s=options.frame_period_s,
        boat_speed_m_s=options.boat_speed_m_s,
        resend_m_during_cast=options.resend_m,
        check_plan=options.check_plan,
        finish_timeout_s=options.finish_timeout_s,
    )
    autopilot = Autopilot(mission, config)
    run = _Run(mission, autopilot, console)
    port = await FramePort.over_serial(options.port, options.baudrate)
    run.attach(port)
    console.start(
        mission,
        f"cc-daemon simulate-autopilot on {options.port} at {options.baudrate} baud: "
        f"{len(mission.stations)} stations, seed {mission.seed}",
    )
    try:
        with _signals(run, options.handle_signals):
            run.t0 = time.monotonic()
            await run.pump(
                lambda: autopilot.phase is Phase.DONE or run.interrupts > 0 or port.hung_up
            )
            if not run.interrupts and not port.hung_up:
                await run.pump(lambda: run.interrupts > 0, deadline=run.now() + LINGER_S)
    finally:
        await run.close()
        console.stop()
    notes = ["the serial port went away"] if port.hung_up else []
    autopilot.finish(run.now(), interrupted=run.interrupts > 0)
    summary = build_summary(
        run, casts=None, daemon_exit=None, db_path=None, log_path=None, notes=notes
    )
    console.print_summary(summary)
    return summary.exit_code


# ---------------------------------------------------------------- command line


def _rate(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text}: a probability per byte, 0..1")
    return value


def _count(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text}: at least 1")
    return value


def _seconds(text: str) -> float:
    value = float(text)
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"{text}: seconds, >= 0")
    return value


def _positive_seconds(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text}: seconds, > 0")
    return value


def _mission_arguments(group: argparse._ArgumentGroup) -> None:
    group.add_argument(
        "--stations", type=_count, default=3, metavar="N", help="stations to visit (3)"
    )
    group.add_argument(
        "--seed", type=int, default=1, metavar="S", help="mission and noise seed (1)"
    )
    group.add_argument(
        "--resend-m",
        action="store_true",
        help="keep resending M during each cast, as a flight plan that keeps the station "
        "selected does (the daemon must still cast once per station)",
    )


def add_simulate_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `cc-daemon --simulate` (the daemon's own flags stay the parser's)."""
    group = parser.add_argument_group(
        "--simulate options",
        "A whole survey on this machine: the daemon against a simulated autopilot over a "
        "pty pair. The journal goes to --db (default ./simulate.db).",
    )
    _mission_arguments(group)
    group.add_argument(
        "--realtime",
        action="store_true",
        help="real speeds: boat 1.5 m/s, the configured winch and cast (minutes per station)",
    )
    group.add_argument(
        "--corrupt",
        type=_rate,
        default=0.0,
        metavar="RATE",
        help="flip one bit in a byte on the link with this probability, both ways (e.g. "
        "0.02), never two bits within 25 bytes (the longest frame): every spoiled frame "
        "fails its checksum, as on a line whose checksum catches every error",
    )
    group.add_argument(
        "--drop-link-at",
        type=_seconds,
        metavar="T",
        help="pull the cable T seconds into the run, for --drop-link-for seconds",
    )
    group.add_argument(
        "--drop-link-for", type=_positive_seconds, default=3.0, metavar="S", help="(3 s)"
    )
    group.add_argument(
        "--winch-stall",
        action="store_true",
        help=f"the simulated winch stalls at {STALL_AT_M:g} m: casts abort and come home",
    )
    group.add_argument(
        "--winch-fail-home",
        action="store_true",
        help="the simulated winch jams on the way home: no R-F, the autopilot gives up",
    )
    group.add_argument("--plain", action="store_true", help="plain log lines even on a terminal")


def options_from_args(args: argparse.Namespace, settings: Settings | None) -> SimOptions:
    return SimOptions(
        stations=args.stations,
        seed=args.seed,
        realtime=args.realtime,
        corrupt=args.corrupt,
        drop_link_at=args.drop_link_at,
        drop_link_for=args.drop_link_for,
        winch_stall=args.winch_stall,
        winch_fail_home=args.winch_fail_home,
        resend_m=args.resend_m,
        db=getattr(args, "db", None),
        live=False if args.plain else None,
        settings=settings,
    )


def run_from_args(args: argparse.Namespace, settings: Settings | None = None) -> int:
    """`cc-daemon --simulate ...`: parse-time options to a finished run's exit status."""
    try:
        options = options_from_args(args, settings)
        make_mission(options.stations, options.seed)  # a mission that cannot be laid out
    except ValueError as exc:
        print(f"cc-daemon --simulate: {exc}", file=sys.stderr)
        return EXIT_USAGE
    return asyncio.run(run_simulation(options))


def add_commands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register `simulate-autopilot`."""
    p = sub.add_parser(
        "simulate-autopilot",
        help="the simulated autopilot alone, on a serial port (against a daemon elsewhere)",
        description="Run the simulated autopilot on a real serial port, e.g. a USB-serial "
        "cable to a Raspberry Pi running cc-daemon. Exit status 0 when every station got "
        "its R-F with no protocol violation.",
    )
    p.add_argument("--port", required=True, help="serial device, e.g. /dev/ttyUSB0")
    p.add_argument("--baudrate", type=int, default=9600, help="(9600, 8N1)")
    group = p.add_argument_group("mission")
    _mission_arguments(group)
    group.add_argument(
        "--frame-period", type=float, default=1.0, metavar="S", help="seconds per frame (1)"
    )
    group.add_argument(
        "--boat-speed", type=float, default=1.5, metavar="M_S", help="transit speed (1.5 m/s)"
    )
    group.add_argument(
        "--finish-timeout",
        type=float,
        default=900.0,
        metavar="S",
        help="give up on a station after this long without R-F (900 s)",
    )
    group.add_argument(
        "--no-plan-check",
        action="store_true",
        help="do not expect the daemon's default plan (the shoal refused, the rest cast)",
    )
    group.add_argument("--plain", action="store_true", help="plain log lines even on a terminal")
    p.set_defaults(handler=_autopilot_handler)


def _autopilot_handler(args: argparse.Namespace) -> int:
    try:
        options = AutopilotOnlyOptions(
            port=args.port,
            baudrate=args.baudrate,
            stations=args.stations,
            seed=args.seed,
            frame_period_s=args.frame_period,
            boat_speed_m_s=args.boat_speed,
            resend_m=args.resend_m,
            check_plan=not args.no_plan_check,
            finish_timeout_s=args.finish_timeout,
            live=False if args.plain else None,
        )
        return asyncio.run(run_autopilot(options))
    except (OSError, ValueError) as exc:  # no such port, permission, bad numbers
        print(f"cc-daemon simulate-autopilot: {exc}", file=sys.stderr)
        return EXIT_USAGE
