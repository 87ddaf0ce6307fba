"""Running a cast: the cast machine's actions carried out against the winch, the link
and the journal, and the helpers every part of the daemon uses to reach those three.

`CastRunner` is the base of `service.Daemon`: the Daemon routes the autopilot's
messages and owns the lifecycle; this owns what happens between a cast's `R-O`
and its `R-F` (or its stranding). The state it uses is declared below and set up
by the Daemon's constructor.

Guarantees kept here:
- `R-F` is sent only from a `SendFinished` the machine produced from a status
  saying the probe is home.
- A cast cancelled or failed stops the motor and says so loudly; after an
  internal error no `R-F` is ever sent and the depth keeps being reported.
- Nothing in the journal can stop the boat (`_journaling`).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Iterator
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
from cc_daemon.core.protocol.messages import CcMessage, DepthReport
from cc_daemon.core.winch.status import Winch, WinchStatus
from cc_daemon.daemon.line_watch import LineWatch
from cc_daemon.daemon.sonde import SondeDuty
from cc_daemon.drivers.link import SerialLink
from cc_daemon.ground.clock import Clock
from cc_daemon.store import Journal

_log = structlog.get_logger("cc_daemon.service")

EXIT_OK = 0
EXIT_PROBE_MAY_BE_DOWN = 130
# The journal dropped rows (no file and no spill file could take them): say so.
EXIT_ROWS_LOST = 4


class ActiveCast:
    def __init__(self, cast_id: int, station: StartMeasuring, machine: CastMachine) -> None:
        self.cast_id = cast_id
        self.station = station
        self.machine = machine
        self.task: asyncio.Task[None] | None = None
        self.reports = 0
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
        assert self._tasks is not None
        cast.task = self._tasks.create_task(self._run_cast(cast), name=f"cast-{cast.cast_id}")

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
            self._send(DepthReport(self._now_ts(), self._depth_mm(depth)))
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
                case CommandWinch(depth_m=depth):
                    assert self._winch is not None
                    commanded = True
                    try:
                        self._winch.move_to(depth)
                    except Exception as exc:
                        _log.error("winch command failed", depth_m=depth, error=str(exc))
                        queue.extend(cast.machine.winch_error(now, f"{type(exc).__name__}: {exc}"))
                case StopWinch(reason=reason):
                    self._stop_motor(reason)
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
                    _log.critical(
                        message,
                        cast_id=cast.cast_id,
                        stranded_for_s=round(now - cast.machine.started_at),
                    )
        return commanded

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
        else:
            _log.info("cast phase", cast_id=cast.cast_id, phase=str(new), depth_m=depth)

    def _finish(self, cast: ActiveCast, action: SendFinished, now: float) -> None:
        # The machine produced SendFinished from a status saying the probe is
        # home, in this same step; reading the winch again here could only
        # disagree with the machine and leave a cast half-ended.
        self._send(Finished(self._time.at(now), self._depth_mm(action.depth_m)))
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
