"""The simulated Paparazzi autopilot: the deployed firmware's behaviour, sans-IO.

This module owns what the autopilot side of the link does and what it checks,
written from the protocol (docs/protocol.md) and the firmware's own code, never
from the daemon's. It is a state machine driven by the caller: `poll(now)`
returns the frames due at `now` (one per frame period), `on_frame(now,
message)` and `on_corrupt(now, error)` take what arrived, `finish(now)` closes
the books; `now` is seconds since the mission started, on any clock.

Two firmware profiles (`AutopilotConfig.firmware`):
- "ucm-2023", the deployed firmware (serial_com.c of 2023, see
  docs/firmware.md): `T` every 1.1 s, timestamps little-endian on the wire,
  the 26-byte `M` (mode byte 0) sent once per station, then silence (no `T`,
  no `S`) until `R-F`; `R-O` and `R-M` are only stored. Optionally a scripted
  RC-stick jog (`P-D`, then `P-U`, no reply expected) on arriving at the
  deepest station, before `M` (`stick_jog`). A repeated `R-F` is accepted.
- "manual", the behaviour below, as the manual describes it.

Behaviour of the "manual" profile:
- one frame per frame period (a second, as the firmware; the demo too);
- cruising: `T` with the position along a straight transit, the altitude and
  the sonar reading;
- at a station: `M` every frame until `R-O` arrives; then, while the probe is
  out, it holds position and sends `T`, with `S` every `query_every`-th frame
  (or keeps resending `M` in place of `T`, as a flight plan that keeps the
  station selected does, with `resend_m_during_cast`);
- it leaves the station only when `R-F` arrives.

It records a `Violation` for: a corrupt frame, `M` or `S` not answered within
`answer_timeout_s`, depth reports stopping for more than `report_gap_s`
during a cast, `R-F` with a non-zero depth, a depth below the bottom or beyond
the line, no `R-F` within `finish_timeout_s` of arriving, a frame that makes
no sense in the current state, and (with `check_plan`) a cast at the shoal or
a refusal at a deep station. Violations that injected noise (a flipped bit
reported with `bits_flipped` inside the check's window) or a pulled cable
(while out, and the daemon's reconnect time after) explain are excused.

It never does I/O, sleeps, reads a clock or looks inside the daemon.
"""

from __future__ import annotations

import random
from bisect import bisect_left
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from cc_daemon.core.protocol import (
    Ack,
    AutopilotMessage,
    CorruptFrame,
    DepthReport,
    FaultReport,
    Finished,
    Message,
    ProbeDown,
    ProbePosition,
    ProbePositionRequest,
    ProbeUp,
    StartMeasuring,
    Telemetry,
)
from cc_daemon.sim.autopilot_config import (
    FIRMWARES,
    UCM_2023_FRAME_PERIOD_S,
    AutopilotConfig,
    Firmware,
)
from cc_daemon.sim.mission import ORIGIN_ALT_M, Mission, Point, SonarReading, Station
from cc_daemon.sim.violations import (
    BITS_FLIPPED,
    EXPLAINED_BY_INBOUND_LOSS,
    EXPLAINED_BY_OUTBOUND_LOSS,
    StationLog,
    Violation,
    ViolationKind,
)

__all__ = [
    "BITS_FLIPPED",
    "FIRMWARES",
    "UCM_2023_FRAME_PERIOD_S",
    "Autopilot",
    "AutopilotConfig",
    "Firmware",
    "Phase",
    "StationLog",
    "Violation",
    "ViolationKind",
]


def _little_endian(stamp: int) -> int:
    """The value the manual's big-endian reading gives a little-endian timestamp."""
    return (stamp & 0xFF) << 8 | stamp >> 8


class Phase(StrEnum):
    CRUISING = "cruising"  # under way to the next station
    JOGGING = "stick jog"  # at a station, the safety pilot jogs the probe first
    REQUESTING = "requesting"  # at a station, sending M until R-O
    CASTING = "casting"  # R-O received, holding position until R-F
    DONE = "done"  # every station visited (or the run was ended)


@dataclass(slots=True)
class _Outage:
    down: float
    up: float | None = None  # None while the cable is out


class Autopilot:
    """See the module docstring. `now` must never go backwards."""

    def __init__(
        self, mission: Mission, config: AutopilotConfig | None = None, *, seed: int | None = None
    ) -> None:
        self.mission = mission
        self.config = config or AutopilotConfig()
        self._rng = random.Random(mission.seed if seed is None else seed)
        self.phase = Phase.CRUISING
        self.index = 0  # the station we are going to, or at
        self.logs = [StationLog(s) for s in mission.stations]
        self.violations: list[Violation] = []
        self.probe_depth_m = 0.0  # the last depth the daemon told us
        self.error_last = 0  # the firmware's receive error: 76 after an R-L, 0 after R-F
        self._leg_started_at: float | None = None
        self._next_frame_at: float | None = None
        self._frames_at_station = 0
        self._pending_m_since: float | None = None
        self._pending_s_since: float | None = None
        self._last_report_at: float | None = None
        self._gap_flagged = False
        self._retrying = False
        self._left_station_at: float | None = None
        self._position = mission.start
        self._outages: list[_Outage] = []
        self._flips_in: list[float] = []  # when bits were flipped on the daemon's frames
        self._flips_out: list[float] = []  # ... and on ours
        self._last_heard_at = 0.0  # the last frame (good or corrupt) from the daemon
        self._jog_frames: list[str] = []  # what the stick still has to send
        self._jog_index: int | None = None
        if self.config.ucm_2023 and self.config.stick_jog:
            depths = [s.water_depth_m for s in mission.stations]
            self._jog_index = depths.index(max(depths))
        self.finished = False
        # The sonar module's latest reading (`sim.sonar_chain`); None: made up from the field.
        self.sonar: Callable[[], SonarReading] | None = None

    # ------------------------------------------------------------ queries

    @property
    def station(self) -> Station | None:
        """The station we are going to or at; None when done."""
        if self.phase is Phase.DONE:
            return None
        return self.mission.stations[self.index]

    @property
    def log(self) -> StationLog | None:
        return None if self.phase is Phase.DONE else self.logs[self.index]

    @property
    def next_deadline(self) -> float:
        """When `poll` next has something to do (a frame is due)."""
        return 0.0 if self._next_frame_at is None else self._next_frame_at

    def position(self, now: float) -> Point:
        self._advance(now)
        return self._position

    def to_go_m(self, now: float) -> float:
        """How far the boat still has to sail to the station it is going to."""
        self._advance(now)
        if self.phase is not Phase.CRUISING or self._leg_started_at is None:
            return 0.0
        travelled = (now - self._leg_started_at) * self.config.boat_speed_m_s
        return self.mission.leg_length_m(self.index) - travelled

    @property
    def problems(self) -> list[Violation]:
        return [v for v in self.violations if not v.excused]

    @property
    def survey_complete(self) -> bool:
        return all(log.finished_at is not None for log in self.logs)

    # ------------------------------------------------------------ the link going away

    def link_down(self, now: float) -> None:
        """The cable is out from `now`: silence until `link_up` (and a grace after) is excused."""
        self._outages.append(_Outage(now))

    def link_up(self, now: float) -> None:
        if self._outages and self._outages[-1].up is None:
            self._outages[-1].up = now

    # ------------------------------------------------------------ injected noise

    def bits_flipped(self, at: float, *, inbound: bool) -> None:
        """Injected noise flipped a bit at `at`: on a frame from the daemon
        (`inbound`) or on one of ours. Times must not go backwards."""
        (self._flips_in if inbound else self._flips_out).append(at)

    # ------------------------------------------------------------ driving

    def poll(self, now: float) -> list[AutopilotMessage]:
        """Check timers and return the frames due at `now` (at most one)."""
        if self._next_frame_at is None:
            self._next_frame_at = now
            self._leg_started_at = now
        self._advance(now)
        self._check_timers(now)
        if self.phase is Phase.DONE or now < self._next_frame_at:
            return []
        period = self.config.frame_period_s
        self._next_frame_at += period
        if self._next_frame_at <= now:  # we were not polled for a while: no burst of catch-up
            self._next_frame_at = now + period
        frame = self._frame(now)
        return [] if frame is None else [frame]

    def on_frame(self, now: float, message: Message) -> None:
        """A frame from the daemon arrived at `now`."""
        if self.finished:
            return  # the books are closed: what comes now is a consequence, not news
        self._advance(now)
        self._last_heard_at = now
        if isinstance(message, Ack):
            self._on_ack(now)
        elif isinstance(message, DepthReport):
            self._on_depth(now, message)
        elif isinstance(message, ProbePosition):
            self._on_probe_position(now, message)
        elif isinstance(message, Finished):
            self._on_finished(now, message)
        elif isinstance(message, FaultReport):
            self._on_fault(now, message)
        else:
            self._violation(
                now, ViolationKind.UNEXPECTED_FRAME, f"{message.frame} is not a CC frame"
            )

    def on_corrupt(self, now: float, error: CorruptFrame) -> None:
        if self.finished:
            return
        # The frame's bytes arrived after the last thing we heard, and before now.
        since, self._last_heard_at = self._last_heard_at, now
        self._violation(
            now,
            ViolationKind.CORRUPT_FRAME,
            f"{error.kind}: {error.hex()} ({error.detail})",
            since=since,
        )

    def finish(self, now: float, *, interrupted: bool = False) -> None:
        """The run is over: a station still waiting for R-F says so."""
        if self.finished:
            return
        self.finished = True
        log = self.log
        if log is not None and log.arrived_at is not None and log.finished_at is None:
            self._violation(
                now,
                ViolationKind.NO_FINISH,
                f"the run ended {now - log.arrived_at:.1f} s after arriving, without R-F",
                excused_by="stopped by the operator" if interrupted else None,
            )
        self.phase = Phase.DONE

    # ------------------------------------------------------------ motion

    def _advance(self, now: float) -> None:
        if self.phase is not Phase.CRUISING or self._leg_started_at is None:
            return
        travelled = (now - self._leg_started_at) * self.config.boat_speed_m_s
        length = self.mission.leg_length_m(self.index)
        if travelled < length:
            self._position = self.mission.along_leg(self.index, travelled)
            return
        self._position, self.phase = self.mission.leg(self.index)[1], Phase.REQUESTING
        if self.index == self._jog_index:
            self.phase = Phase.JOGGING
            self._jog_frames = [kind for kind, n in self.config.jog_script for _ in range(n)]
        self._frames_at_station = 0
        self.logs[self.index].arrived_at = self._leg_started_at + length / (
            self.config.boat_speed_m_s
        )

    def _leave_station(self, now: float) -> None:
        self._left_station_at = now
        self._pending_m_since = self._pending_s_since = None
        self._last_report_at = None
        self._gap_flagged = self._retrying = False
        self.index += 1
        if self.index >= len(self.mission.stations):
            self.index = len(self.mission.stations) - 1
            self.phase = Phase.DONE
            return
        self.phase = Phase.CRUISING
        self._leg_started_at = now

    # ------------------------------------------------------------ frames out

    def _frame(self, now: float) -> AutopilotMessage | None:
        stamp = int(now) & 0xFFFF  # whole seconds since boot, as the firmware counts
        log = self.logs[self.index]
        settling = log.arrived_at is not None and now - log.arrived_at < self.config.settle_s
        if self.config.ucm_2023:
            stamp = _little_endian(stamp)
            if self.phase is Phase.JOGGING:
                return self._jog_frame(stamp, log)
            waiting = self.phase is Phase.CASTING or (
                self.phase is Phase.REQUESTING and log.m_sent > 0
            )
            if waiting and not self.config.resend_m_during_cast:
                return None  # M once, then silence until R-F: no T, no S
            if waiting:
                return self._start_measuring(now, stamp, log)  # a later line resends
        if self.phase is Phase.REQUESTING and not settling:
            return self._start_measuring(now, stamp, log)
        if self.phase is Phase.CASTING:
            self._frames_at_station += 1
            if self._frames_at_station % self.config.query_every == 0:
                log.s_sent += 1
                if self._pending_s_since is None:
                    self._pending_s_since = now
                request: ProbePositionRequest = ProbePositionRequest(stamp)
                return request
            if self.config.resend_m_during_cast or self._retrying:
                return self._start_measuring(now, stamp, log)
        telemetry: Telemetry = Telemetry(stamp, *self._fix(moving=self.phase is Phase.CRUISING))
        return telemetry

    def _start_measuring(self, now: float, stamp: int, log: StationLog) -> StartMeasuring:
        log.m_sent += 1
        if self._pending_m_since is None:
            self._pending_m_since = now
        mode = 0 if self.config.ucm_2023 else None  # the firmware's 26-byte M, mode 0
        message: StartMeasuring = StartMeasuring(stamp, *self._fix(moving=False), mode)
        return message

    def _jog_frame(self, stamp: int, log: StationLog) -> AutopilotMessage:
        kind = self._jog_frames.pop(0)
        if not self._jog_frames:
            self.phase = Phase.REQUESTING  # the stick is left alone: now the station
        frame: AutopilotMessage
        if kind == "D":
            log.stick_down += 1
            frame = ProbeDown(stamp)
        elif kind == "U":
            log.stick_up += 1
            frame = ProbeUp(stamp)
        else:
            frame = Telemetry(stamp, *self._fix(moving=False))
        return frame

    def _fix(self, *, moving: bool) -> tuple[int, int, int, int, int]:
        lon, lat = self._position.e7
        if self.sonar is not None:
            sonar = self.sonar()
        else:
            sonar = self.mission.sonar(self._position, moving=moving, rng=self._rng)
        alt_mm = round((ORIGIN_ALT_M + self._rng.uniform(-0.03, 0.03)) * 1000)  # a ripple
        return lon, lat, alt_mm, sonar.distance_mm, sonar.confidence_pct

    # ------------------------------------------------------------ frames in

    def _at_station(self) -> bool:
        return self.phase in (Phase.REQUESTING, Phase.CASTING)

    def _just_left(self, now: float) -> bool:
        left = self._left_station_at
        return left is not None and now - left <= self.config.station_grace_s

    def _on_ack(self, now: float) -> None:
        self._pending_m_since = None
        if self.phase is Phase.REQUESTING:
            self._start_cast(now)
        elif self.phase is not Phase.CASTING and not self._just_left(now):
            self._violation(now, ViolationKind.UNEXPECTED_FRAME, "R-O with no M outstanding")
        # While casting, an R-O does not end a retry: M is resent until the
        # daemon shows progress, an R-M or the R-F a finished cast answers M
        # with (after its R-O; and that R-F can be lost as well).

    def _start_cast(self, now: float) -> None:
        self.phase = Phase.CASTING
        self.logs[self.index].acked_at = now
        self._last_report_at = now
        self._frames_at_station = 0

    def _on_depth(self, now: float, message: DepthReport) -> None:
        if self.phase is Phase.REQUESTING:
            self._start_cast(now)  # R-O was lost on the way; the cast is evidently running
        if self.phase is not Phase.CASTING:
            self._violation(
                now,
                ViolationKind.UNEXPECTED_FRAME,
                f"R-M depth {message.depth_m:.3f} m with no cast running",
            )
            return
        self._check_depth(now, "R-M", message.depth_mm)
        log = self.logs[self.index]
        log.reports += 1
        log.max_depth_m = max(log.max_depth_m, message.depth_m)
        self.probe_depth_m = message.depth_m
        self._last_report_at = now
        self._gap_flagged = self._retrying = False

    def _on_fault(self, now: float, message: FaultReport) -> None:
        """`R-L`: both 2023 revisions store it as their receive error (76) for the
        ground station and keep waiting at the station: so do both profiles."""
        if self.phase is Phase.REQUESTING:
            self._start_cast(now)  # R-O was lost on the way
        if self.phase is not Phase.CASTING:
            if not self._just_left(now):
                self._violation(now, ViolationKind.UNEXPECTED_FRAME, "R-L with no cast running")
            return
        log = self.logs[self.index]
        log.fault_reports += 1
        log.fault_depth_m = self.probe_depth_m = message.depth_m
        self.error_last = 76
        self._last_report_at = now  # the daemon is speaking: not a silent gap
        self._gap_flagged = self._retrying = False

    def _on_probe_position(self, now: float, message: ProbePosition) -> None:
        if self._pending_s_since is None and not self._just_left(now):
            self._violation(now, ViolationKind.UNEXPECTED_FRAME, "R-P with no S outstanding")
        self._pending_s_since = None
        self._check_depth(now, "R-P", message.depth_mm)
        self.probe_depth_m = message.depth_m

    def _on_finished(self, now: float, message: Finished) -> None:
        if message.depth_mm != 0:
            self._violation(
                now,
                ViolationKind.FINISHED_NOT_HOME,
                f"R-F says the probe is at {message.depth_m:.3f} m: the boat would drag it",
            )
        if not self._at_station():
            # The 2023 firmware takes a repeated R-F as it takes any: no harm.
            if not self._just_left(now) and not self.config.ucm_2023:
                self._violation(now, ViolationKind.UNEXPECTED_FRAME, "R-F with no cast running")
            return
        self.probe_depth_m = message.depth_m
        self.error_last = 0
        log = self.logs[self.index]
        log.finished_at = now
        log.finish_depth_mm = message.depth_mm
        if self.config.check_plan:
            if log.reports == 0 and not log.station.too_shallow:
                # With the cable out during the station, the R-M were lost on it: the
                # R-F (or its repeat) that arrives after cannot tell a refusal.
                since = log.acked_at if log.acked_at is not None else now
                self._violation(
                    now,
                    ViolationKind.UNEXPECTED_SKIP,
                    f"R-F without a cast in {log.station.water_depth_m:.2f} m of water",
                    excused_by=self._cable_out(since, now),
                )
            elif log.reports > 0 and log.station.too_shallow:
                self._violation(
                    now,
                    ViolationKind.UNEXPECTED_CAST,
                    f"probe lowered in {log.station.water_depth_m:.2f} m of water",
                )
        self._leave_station(now)

    def _check_depth(self, now: float, frame: str, depth_mm: int) -> None:
        depth = depth_mm / 1000.0
        tolerance = self.config.depth_tolerance_m
        if depth > self.config.max_line_m + tolerance:
            self._violation(
                now,
                ViolationKind.DEPTH_OUT_OF_RANGE,
                f"{frame} depth {depth:.3f} m is beyond {self.config.max_line_m} m of line",
            )
        elif self._at_station():
            bottom = self.logs[self.index].station.water_depth_m
            if depth > bottom + tolerance:
                self._violation(
                    now,
                    ViolationKind.DEPTH_OUT_OF_RANGE,
                    f"{frame} depth {depth:.3f} m is below the bottom at {bottom:.3f} m",
                )

    # ------------------------------------------------------------ timers

    def _check_timers(self, now: float) -> None:
        config = self.config
        since = self._pending_m_since
        if since is not None and now - since > config.answer_timeout_s:
            self._pending_m_since = None
            self._violation(
                now,
                ViolationKind.NO_ACK,
                f"no R-O or R-F within {config.answer_timeout_s:g} s of M",
                since=since,
            )
        since = self._pending_s_since
        if since is not None and now - since > config.answer_timeout_s:
            self._pending_s_since = None
            self._violation(
                now,
                ViolationKind.NO_PROBE_ANSWER,
                f"no R-P within {config.answer_timeout_s:g} s of S",
                since=since,
            )
        last = self._last_report_at
        if (
            self.phase is Phase.CASTING
            and last is not None
            and not self._gap_flagged
            and now - last > config.report_gap_s
        ):
            self._gap_flagged = True
            # The station is still selected: resend M until the daemon
            # answers, as a flight plan holding the station does. A lost R-F
            # is repeated then. The 2023 firmware sends M once, never again.
            self._retrying = not self.config.ucm_2023
            self._violation(
                now,
                ViolationKind.REPORT_GAP,
                f"no R-M for more than {config.report_gap_s:g} s during the cast",
                since=last,
            )
        log = self.log
        if (
            log is not None
            and self._at_station()
            and log.arrived_at is not None
            and now - log.arrived_at > config.finish_timeout_s
        ):
            self._violation(
                now,
                ViolationKind.NO_FINISH,
                f"no R-F {config.finish_timeout_s:g} s after arriving; giving up on the station "
                f"with the probe last reported at {self.probe_depth_m:.2f} m",
                excused_by=self._only_m_lost(log),
            )
            self.finished = True
            self.phase = Phase.DONE  # a boat must not leave with the probe possibly down

    # ------------------------------------------------------------ violations

    def _violation(
        self,
        now: float,
        kind: ViolationKind,
        detail: str,
        *,
        since: float | None = None,
        excused_by: str | None = None,
    ) -> None:
        if excused_by is None:
            excused_by = self._excuse(kind, now if since is None else since, now)
        station = self.logs[self.index].station.number if self._at_station() else None
        violation = Violation(now, kind, detail, station, excused_by)
        self.violations.append(violation)
        if station is not None:
            self.logs[self.index].violations.append(violation)

    def _only_m_lost(self, log: StationLog) -> str | None:
        """The 2023 firmware sends M once: that M lost to the injected noise or cable, no
        daemon could end the station (it can only say it suspects so: a lost M)."""
        lost = [v for v in log.violations if v.kind is ViolationKind.NO_ACK and v.excused]
        if not self.config.ucm_2023 or log.acked_at is not None or not lost:
            return None
        return f"its only M was lost ({lost[0].excused_by}); the 2023 firmware never resends it"

    def _cable_out(self, since: float, now: float) -> str | None:
        """The excuse of a cable pulled within [since, now] (and the reconnect after)."""
        for outage in self._outages:
            up = outage.up
            end = float("inf") if up is None else up + self.config.outage_grace_s
            if since <= end and now >= outage.down:
                return "the cable was unplugged"
        return None

    def _excuse(self, kind: ViolationKind, since: float, now: float) -> str | None:
        config = self.config
        if kind in EXPLAINED_BY_INBOUND_LOSS and (cable := self._cable_out(since, now)):
            return cable
        # A corrupt frame's bytes arrived after whatever came before it: its
        # window is exact. A missing answer may be the victim of a frame
        # mangled just before the window opened.
        margin = max(config.noise_margin_s, config.frame_period_s)
        start = since if kind is ViolationKind.CORRUPT_FRAME else since - margin
        if kind in EXPLAINED_BY_INBOUND_LOSS and _any_between(self._flips_in, start, now):
            return BITS_FLIPPED
        if kind in EXPLAINED_BY_OUTBOUND_LOSS and _any_between(self._flips_out, start, now):
            return BITS_FLIPPED
        return None


def _any_between(times: list[float], start: float, end: float) -> bool:
    """Whether the sorted `times` hold one in [start, end]."""
    i = bisect_left(times, start)
    return i < len(times) and times[i] <= end
