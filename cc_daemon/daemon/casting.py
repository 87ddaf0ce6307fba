"""Running a cast: the cast machine's actions carried out against the winch, the link
and the journal, and the helpers every part of the daemon uses to reach those three.

`CastRunner` is the base of `service.Daemon`: the Daemon routes the autopilot's
messages and owns the lifecycle; this owns what happens between a cast's `R-O`
and its `R-F` (or its stranding), a shutdown's bringing the probe home included.
The state it uses is declared below and set up by the Daemon's constructor.

Guarantees kept here:
- `R-F` is sent only from a `SendFinished` the machine produced from a status
  saying the probe is home, and always carries depth 0.
- While the probe may be down and cannot come home (stranded, a refused
  station, an internal error) the depth goes out as `R-L`, never `R-M`: the
  firmware hands the code to the ground station and keeps the boat waiting.
- A cast cancelled or failed stops the motor and says so loudly; after an
  internal error no `R-F` is ever sent and the depth keeps being reported.
- Nothing in the journal can stop the boat (`_journaling`).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Iterator
from logging import DEBUG
from typing import Any

import structlog

from cc_daemon.config import Settings
from cc_daemon.core.cast.machine import (
    Action,
    Alarm,
    CastMachine,
    CommandWinch,
    Outcome,
    PhaseChanged,
    ReportDepth,
    SendFinished,
    StopWinch,
)
from cc_daemon.core.cast.plan import Phase
from cc_daemon.core.cast.stations import StationMemory
from cc_daemon.core.cast.timestamps import AutopilotTime
from cc_daemon.core.protocol import Finished, StartMeasuring, as_dict, encode
from cc_daemon.core.protocol.messages import CcMessage, DepthReport, FaultReport
from cc_daemon.core.winch.status import (
    ApproachSpeed,
    LimitedSpeed,
    Winch,
    WinchStatus,
    verified_home,
)
from cc_daemon.daemon.line_watch import LineWatch
from cc_daemon.daemon.sonde import SondeDuty
from cc_daemon.daemon.systemd import SystemdNotifier
from cc_daemon.drivers.link import SerialLink
from cc_daemon.drivers.winch.factory import hand_move
from cc_daemon.ground.clock import Clock
from cc_daemon.ground.logsetup import logs_at
from cc_daemon.store import Journal
from cc_daemon.store.interrupted import InterruptedCast

_log = structlog.get_logger("cc_daemon.service")

EXIT_OK = 0
EXIT_PROBE_MAY_BE_DOWN = 130
# The journal dropped rows (no file and no spill file could take them): say so.
EXIT_ROWS_LOST = 5
SHUTDOWN_EXTEND_S = 30.0  # each EXTEND_TIMEOUT_USEC asks systemd for this much more


class ActiveCast:
    def __init__(self, cast_id: int, station: StartMeasuring, machine: CastMachine) -> None:
        self.cast_id = cast_id
        self.station = station
        self.machine = machine
        self.task: asyncio.Task[None] | None = None
        self.reports = 0
        self.told_no_approach_speed = False  # said once a cast (`CastRunner._move`)
        self.told_no_speed_limit = False  # said once a cast (`CastRunner._move`)
        self.fault_reports = 0  # R-L sent for this station
        # Set when the cast can make no progress without an operator: the probe
        # is stranded, or the cast task failed. Shutdown stops waiting then.
        self.settled = asyncio.Event()


class CastRunner:
    """The daemon's cast execution and shared helpers (see the module docstring)."""

    # Set up by `service.Daemon.__init__`.
    settings: Settings
    link: SerialLink
    frames_out: int
    casts_completed: int
    casts_aborted: int
    _clock: Clock
    _winch: Winch | None
    _journal: Journal | None
    _cast: ActiveCast | None
    _tasks: asyncio.TaskGroup | None
    _exit_code: int
    _shutting_down: bool
    _stations: StationMemory
    _time: AutopilotTime
    _line: LineWatch
    _sonde: SondeDuty | None
    _last_depth_m: float
    _interrupted: list[InterruptedCast]
    _notifier: SystemdNotifier

    def _winch_status(self) -> WinchStatus:
        """The winch's status; if the backend fails, a faulted status at the last depth."""
        assert self._winch is not None
        try:
            status = self._winch.status()
        except Exception as exc:
            return WinchStatus(self._last_depth_m, False, False, f"{type(exc).__name__}: {exc}")
        self._last_depth_m = status.depth_m
        return status

    def _probe_depth(self) -> float:
        return self._winch_status().depth_m if self._winch is not None else 0.0

    def _send(self, message: CcMessage) -> bool:
        sent = self._write_again(encode(message))
        if logs_at(DEBUG):  # asked first: the fields cost more than the question
            _log.debug("frame out", sent=sent, **as_dict(message))
        if isinstance(message, Finished):
            self._line.finished_sent(message, self._clock.monotonic())
        return sent

    def _write_again(self, frame: bytes) -> bool:
        sent = self.link.write(frame)
        self.frames_out += sent
        return sent

    def _now_ts(self) -> int:
        return self._time.at(self._clock.monotonic())

    def _depth_mm(self, depth_m: float) -> int:
        return max(0, round(depth_m * 1000))

    def _start_cast(self, station: StartMeasuring, machine: CastMachine, now: float) -> None:
        plan = machine.plan
        cast_id = self._journal_start(station, plan.depth_m, plan.describe())
        cast = ActiveCast(cast_id if cast_id is not None else -1, station, machine)
        self._cast = cast
        with self._journaling("record_sample") as journal:
            if journal is not None:  # the profile's first point: where the probe was at R-O
                journal.record_sample(cast.cast_id, self._probe_depth(), str(machine.phase))
        _log.info(
            "cast started",
            cast_id=cast.cast_id,
            depth_m=round(plan.depth_m, 3),
            limited_by=plan.limited_by,
            water_depth_m=plan.water_depth_m,
            mode=plan.mode,
        )
        if plan.blind is not None:
            # No bottom to stop above: the plan says so in the cast's row, and this
            # event makes it findable among the station's other events.
            _log.warning(
                "no trusted sonar bottom: casting blind",
                cast_id=cast.cast_id,
                reason=plan.blind,
                max_depth_m=round(plan.depth_m, 3),
            )
            self._journal_event(
                "cast_blind", cast_id=cast.cast_id, reason=plan.blind, depth_m=plan.depth_m
            )
        assert self._tasks is not None
        cast.task = self._tasks.create_task(self._run_cast(cast), name=f"cast-{cast.cast_id}")

    def _release_interrupted(self) -> None:
        """The link is up: free each station a killed run left the boat waiting at
        (`daemon.restart`): R-F at a verified home, else R-L until there."""
        pending, self._interrupted = self._interrupted, []
        for interrupted in pending:
            status = self._winch_status()
            if verified_home(status) and self._cast is None:
                self._send(Finished(self._now_ts(), 0))
                _log.warning(
                    "station of the interrupted cast released: the probe is home, R-F sent",
                    cast_id=interrupted.cast_id,
                )
                self._journal_event("cast_recovered", cast_id=interrupted.cast_id, rf_sent=True)
            elif self._cast is None:
                station = StartMeasuring(0, interrupted.lon_e7, interrupted.lat_e7, 0, 0, 0)
                fault = status.fault or f"probe {status.depth_m:.2f} m down after a restart"
                self._refuse_cast(station, status._replace(fault=fault), self._clock.monotonic())
                self._journal_event(
                    "cast_recovered", cast_id=interrupted.cast_id, rf_sent=False, held_by_r_l=True
                )

    def _refuse_cast(self, station: StartMeasuring, status: WinchStatus, now: float) -> None:
        """No cast on a winch that cannot vouch for home (its homing failed, a fault
        with the probe not verified home): the station is held with R-L at once
        and every period, and released with R-F only at a verified home."""
        fault = status.fault or "winch fault"
        _log.critical(
            "start-measuring refused: the winch cannot verify home; reporting the fault",
            fault=fault,
            depth_m=round(status.depth_m, 3),
        )
        self._journal_event("cast_refused", fault=fault, depth_m=round(status.depth_m, 3))
        machine = CastMachine.refused(
            started_at=now,
            report_period_s=self.settings.cast.report_period_s,
            depth_m=status.depth_m,
            fault=fault,
        )
        self._start_cast(station, machine, now)

    async def _run_cast(self, cast: ActiveCast) -> None:
        machine = cast.machine
        winch = self._winch
        assert winch is not None
        try:
            while not machine.finished:
                actions = machine.step(self._clock.monotonic(), self._winch_status())
                commanded = self._execute(cast, actions)
                if machine.finished:
                    break
                if machine.phase is Phase.STRANDED:
                    cast.settled.set()
                if commanded:
                    continue  # look at the winch again before sleeping
                timeout = machine.next_deadline() - self._clock.monotonic()
                try:
                    await winch.wait_change(timeout)
                except Exception as exc:
                    self._execute(
                        cast, machine.winch_error(self._clock.monotonic(), f"wait failed: {exc}")
                    )
                    await asyncio.sleep(max(timeout, 0.0))
        except asyncio.CancelledError:
            self._stop_motor("cast cancelled")
            if not self._winch_status().at_home and self._exit_code != EXIT_PROBE_MAY_BE_DOWN:
                _log.critical(
                    "cast cancelled with the probe down: winch stopped",
                    cast_id=cast.cast_id,
                    depth_m=round(self._probe_depth(), 3),
                )
            raise
        except Exception:
            # A bug in our own code: stop the motor and say so as loudly as we can.
            self._stop_motor("internal error")
            _log.critical(
                "internal error in the cast: winch stopped, the probe may be down",
                cast_id=cast.cast_id,
                exc_info=True,
            )
            cast.settled.set()
            await self._alarm_until_stopped(cast)
        self._cast = None

    async def _alarm_until_stopped(self, cast: ActiveCast) -> None:
        """After an internal error: no R-F ever; keep reporting the depth the
        winch gives and keep saying so, every report period, until shutdown."""
        try:
            await self._alarm_every_period(cast)
        finally:
            self._stop_motor("alarm loop ended")

    async def _alarm_every_period(self, cast: ActiveCast) -> None:
        period = self.settings.cast.report_period_s
        next_at = self._clock.monotonic()  # the first report at once: no gap
        while True:
            await self._clock.sleep_until(next_at)
            next_at += period
            depth = self._probe_depth()
            self._report_fault(cast, depth, "internal error: probe state unknown")
            _log.critical(
                "PROBE STATE UNKNOWN after an internal error: no R-F will be sent; "
                "the winch motor is stopped; operator intervention needed",
                cast_id=cast.cast_id,
                depth_m=round(depth, 3),
                for_s=round(self._clock.monotonic() - cast.machine.started_at),
            )

    def _execute(self, cast: ActiveCast, actions: list[Action]) -> bool:
        """Carry out the machine's actions; True if the winch was commanded."""
        commanded = False
        queue = list(actions)
        while queue:
            action = queue.pop(0)
            now = self._clock.monotonic()
            match action:
                case CommandWinch(depth_m=depth, slow=slow, max_speed_m_s=limit):
                    commanded = True
                    try:
                        self._move(cast, depth, slow=slow, max_speed_m_s=limit)
                    except Exception as exc:
                        _log.error("winch command failed", depth_m=depth, error=str(exc))
                        queue.extend(cast.machine.winch_error(now, f"{type(exc).__name__}: {exc}"))
                case StopWinch(reason=reason):
                    self._stop_motor(reason)
                case ReportDepth(depth_m=depth, phase=Phase.STRANDED):
                    self._report_fault(cast, depth, cast.machine.winch_fault)
                    with self._journaling("record_sample") as journal:
                        if journal is not None:
                            journal.record_sample(cast.cast_id, depth, str(Phase.STRANDED))
                case ReportDepth(depth_m=depth, phase=phase):
                    cast.reports += 1
                    told = self._sonde.report_depth(depth, now) if self._sonde else depth
                    self._send(DepthReport(self._time.at(now), self._depth_mm(told)))
                    with self._journaling("record_sample") as journal:
                        if journal is not None:
                            journal.record_sample(cast.cast_id, depth, str(phase))
                case SendFinished():
                    self._finish(cast, action, now)
                case PhaseChanged(old=old, new=new, reason=reason):
                    self._phase_changed(cast, old, new, reason)
                case Alarm(message=message):
                    # Identical each period while nothing changes, so the log's rate
                    # limiter passes one per window with a count (the R-L goes each period).
                    _log.critical(message, cast_id=cast.cast_id)
        return commanded

    def _move(
        self, cast: ActiveCast, depth_m: float, *, slow: bool, max_speed_m_s: float | None
    ) -> None:
        """Run the winch to `depth_m`; `slow`: at its approach speed where it has one;
        `max_speed_m_s`: no faster, where it can be told (a profile's descent)."""
        winch = self._winch
        assert winch is not None
        if not slow and max_speed_m_s is not None and isinstance(winch, LimitedSpeed):
            winch.move_at_most(depth_m, max_speed_m_s)
        elif not slow:
            if max_speed_m_s is not None and not cast.told_no_speed_limit:
                cast.told_no_speed_limit = True
                _log.warning(
                    "this winch runs at one speed: descending faster than the profile's "
                    "resolution asks",
                    cast_id=cast.cast_id,
                    max_speed_m_s=round(max_speed_m_s, 4),
                    backend=self.settings.winch.backend,
                )
            winch.move_to(depth_m)
        elif isinstance(winch, ApproachSpeed):
            winch.move_slowly_to(depth_m)
        else:
            if not cast.told_no_approach_speed:
                cast.told_no_approach_speed = True
                _log.warning(
                    "blind cast: this winch has no approach speed; paying out at its one speed",
                    cast_id=cast.cast_id,
                    backend=self.settings.winch.backend,
                )
            winch.move_to(depth_m)

    def _report_fault(self, cast: ActiveCast, depth_m: float, fault: str | None) -> None:
        """`R-L` with the best depth we have, in place of `R-M`: the firmware shows
        the code to the ground station and keeps the boat at the station. The
        first of a stranding is journaled; the alarm in the log goes with each."""
        self._send(FaultReport(self._now_ts(), self._depth_mm(depth_m)))
        cast.fault_reports += 1
        if cast.fault_reports == 1:
            self._journal_event(
                "fault_reported", cast_id=cast.cast_id, depth_m=round(depth_m, 3), fault=fault
            )

    async def _finish_running_cast(self) -> None:
        """Bring a running cast home; give up only on a probe that cannot come home."""
        cast = self._cast
        if cast is None or cast.task is None:
            return
        if self._exit_code == EXIT_OK and not cast.settled.is_set():
            _log.info("shutdown: bringing the probe home before exiting", cast_id=cast.cast_id)
            self._execute(cast, cast.machine.abort(self._clock.monotonic(), "shutdown"))
        settled = asyncio.ensure_future(cast.settled.wait())
        try:
            while not (cast.task.done() or settled.done()):
                # Keep systemd from escalating to SIGKILL while the probe comes up.
                self._notifier.notify(
                    f"EXTEND_TIMEOUT_USEC={int(SHUTDOWN_EXTEND_S * 1e6)}",
                    f"STATUS=stopping: bringing the probe home from {self._probe_depth():.1f} m",
                )
                await asyncio.wait(
                    {cast.task, settled},
                    timeout=SHUTDOWN_EXTEND_S / 3,
                    return_when=asyncio.FIRST_COMPLETED,
                )
        finally:
            settled.cancel()
        if not cast.task.done():
            # Stranded or failed: waiting longer cannot bring the probe home.
            self._exit_code = EXIT_PROBE_MAY_BE_DOWN
            _log.critical(
                "exiting with the probe NOT home: the winch is stopped; recover it by hand",
                cast_id=cast.cast_id,
                depth_m=round(self._probe_depth(), 3),
            )
            cast.task.cancel()
        await asyncio.wait({cast.task})  # a cancellation of run() itself still propagates

    def _check_home_at_exit(self) -> None:
        """Exit 0 means the probe is home: a winch that cannot verify it says so."""
        if self._exit_code != EXIT_OK or self._winch is None:
            return
        status = self._winch_status()
        if not verified_home(status):
            self._exit_code = EXIT_PROBE_MAY_BE_DOWN
            _log.critical(
                "exiting with the probe NOT verified home: recover it by hand",
                depth_m=round(status.depth_m, 3),
                at_home=status.at_home,
                fault=status.fault,
            )

    async def _serve_control(self) -> None:
        from cc_daemon.daemon.control_server import serve_control

        await serve_control(
            self.settings.status,
            self.release_station,
            self.haul_home,
            journal=self.settings.store.path,
        )

    def haul_home(self, peer: object, reason: str) -> tuple[bool, str]:
        """`cc-daemon winch home` with the daemon running: haul a stranded probe in.
        The station ends (R-F) only if the winch then verifies home."""
        cast = self._cast
        if cast is None or cast.machine.phase is not Phase.STRANDED or self._winch is None:
            return False, "no stranded probe to haul in (stop the daemon to drive the winch)"
        _log.warning("operator: hauling the stranded probe in", peer=str(peer), reason=reason)
        self._journal_event("operator_haul_in", cast_id=cast.cast_id, peer=str(peer))
        try:
            # An operator's haul: the GPIO winch takes it while its witnesses disagree
            # (it is the haul that can make them agree again); others move as ever.
            hand_move(self._winch, 0.0)
        except Exception as exc:
            return False, f"the winch refused: {type(exc).__name__}: {exc}"
        return True, "hauling the probe in: R-F goes once the winch verifies home"

    def release_station(self, peer: object, reason: str) -> tuple[bool, str]:
        """`cc-daemon release`: an operator who has seen the probe on board ends a
        stranded station (R-F, depth 0). Nothing else: no cast is stranded, no release."""
        cast = self._cast
        if cast is None or cast.machine.phase is not Phase.STRANDED:
            _log.warning("operator release refused: no stranded station", peer=str(peer))
            return False, "no stranded station to release"
        depth = round(cast.machine.depth_m, 3)
        _log.critical(
            "OPERATOR RELEASE: the station is released with the winch unable to verify home",
            cast_id=cast.cast_id,
            reason=reason,
            peer=str(peer),
            winch_depth_m=depth,
        )
        self._journal_event(
            "operator_release",
            cast_id=cast.cast_id,
            reason=reason,
            peer=str(peer),
            winch_depth_m=depth,
            fault=cast.machine.winch_fault,
        )
        self._execute(cast, cast.machine.operator_release(reason))
        return True, f"station released: R-F sent (cast {cast.cast_id})"

    def bottom_contact(self, depth_m: float) -> None:
        """The sonde says the probe is on the bottom: stop paying out, go on from there."""
        cast = self._cast
        if cast is not None:
            self._execute(cast, cast.machine.bottom_contact(self._clock.monotonic(), depth_m))

    def _phase_changed(self, cast: ActiveCast, old: Phase, new: Phase, reason: str | None) -> None:
        depth = round(cast.machine.depth_m, 3)
        if new is Phase.ABORTING:
            # A requested stop (systemctl restart, Ctrl-C) is routine, not an error.
            requested = self._shutting_down and not cast.machine.winch_fault
            (_log.warning if requested else _log.error)(
                "cast cut short by a requested shutdown: bringing the probe home"
                if requested
                else "cast aborted: bringing the probe home",
                cast_id=cast.cast_id,
                reason=reason,
                depth_m=depth,
            )
            self._journal_event("cast_aborted", cast_id=cast.cast_id, reason=reason, depth_m=depth)
            if cast.machine.winch_fault:
                self._journal_event(
                    "winch_fault", cast_id=cast.cast_id, fault=cast.machine.winch_fault
                )
        elif new is Phase.STRANDED:
            self._journal_event("cast_stranded", cast_id=cast.cast_id, reason=reason, depth_m=depth)
        elif old is Phase.STRANDED:
            _log.warning(
                "stranded probe verified home: the fault is cleared, R-F goes",
                cast_id=cast.cast_id,
                fault_reports=cast.fault_reports,
            )
            self._journal_event(
                "stranded_cleared", cast_id=cast.cast_id, fault_reports=cast.fault_reports
            )
        else:
            _log.info("cast phase", cast_id=cast.cast_id, phase=str(new), depth_m=depth)

    def _finish(self, cast: ActiveCast, action: SendFinished, now: float) -> None:
        # The machine produced SendFinished from a status saying the probe is
        # home, in this same step; reading the winch again here could only
        # disagree with the machine and leave a cast half-ended.
        # R-F means "home": its depth is 0, whatever small figure the winch gives.
        self._send(Finished(self._time.at(now), 0))
        with self._journaling("end_cast") as journal:
            if journal is not None:
                # The profile's last point: the probe home, when R-F went out.
                journal.record_sample(cast.cast_id, action.depth_m, str(action.last_phase))
                journal.end_cast(
                    cast.cast_id,
                    outcome=str(action.outcome),
                    reached_depth_m=cast.machine.reached_depth_m,
                    reason=action.reason,
                )
        self._stations.finished(cast.station, now, cast.cast_id)
        self._line.cast_ended(now)
        if action.outcome is Outcome.COMPLETED:
            self.casts_completed += 1
        else:
            self.casts_aborted += 1
        _log.info(
            "cast finished: probe home, R-F sent",
            cast_id=cast.cast_id,
            outcome=str(action.outcome),
            reason=action.reason,
            reached_depth_m=round(cast.machine.reached_depth_m, 3),
            duration_s=round(now - cast.machine.started_at, 1),
            reports=cast.reports,
        )

    def _stop_motor(self, reason: str) -> None:
        winch = self._winch
        if winch is None:
            return
        try:
            winch.stop()
        except Exception:
            _log.critical("COULD NOT STOP THE WINCH MOTOR", reason=reason, exc_info=True)

    @contextlib.contextmanager
    def _journaling(self, what: str) -> Iterator[Journal | None]:
        """Yield the journal; whatever goes wrong in it, the boat goes on."""
        try:
            yield self._journal
        except Exception:
            _log.error("journal call failed", what=what, exc_info=True)

    def _journal_start(
        self, station: StartMeasuring, planned_depth_m: float, plan: dict[str, object]
    ) -> int | None:
        with self._journaling("start_cast") as journal:
            if journal is not None:
                mode = str(plan.get("mode", self.settings.cast.mode))
                return journal.start_cast(
                    station, planned_depth_m=planned_depth_m, mode=mode, plan=plan
                )
        return None

    def _journal_event(self, kind: str, **detail: Any) -> None:
        with self._journaling(kind) as journal:
            if journal is not None:
                journal.record_event(kind, **detail)
