"""The cast state machine: the one place that decides what the winch does.

Pure (sans-IO): it is fed the time and the winch's status and returns actions
for the shell to carry out (command the winch, send a depth report, send R-F,
raise an alarm). It never sleeps, never reads a clock, never touches a port.

States are `Phase` values; `_ALLOWED` is the table of legal transitions and an
illegal one raises `TransitionError` (a bug, not an input problem).

Safety rules enforced here:
- `SendFinished` (R-F) is only ever produced when the winch says the probe is
  home. A fault, a timeout or a shutdown moves to ABORTING, which brings the
  probe home first.
- If the probe cannot be brought home the cast is STRANDED: the motor is
  stopped, no R-F is sent, the shell reports the last known depth as `R-L` (the
  fault report the firmware hands to the ground station) every report period
  and an alarm is raised with it. STRANDED is left only when the winch reports
  the probe verified home again (`verified_home`: an operator hauled it in).
- A station on a winch that refuses casts (`refused`) starts STRANDED: R-O,
  then R-L at once and every period, never a cast, R-F only at a verified home.
- Depth reports are due on absolute deadlines `started_at + k * period`, so
  they never drift; a late step sends one report, never a burst.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

from cc_daemon.core.cast.plan import CastPlan, Leg, Move, Phase
from cc_daemon.core.errors import TransitionError
from cc_daemon.core.winch.status import WinchStatus, verified_home


class Outcome(StrEnum):
    COMPLETED = "completed"
    SKIPPED_SHALLOW = "skipped-shallow"
    ABORTED = "aborted"
    UNFINISHED = "unfinished"


@dataclass(frozen=True, slots=True)
class CommandWinch:
    depth_m: float
    slow: bool = False  # at the winch's approach speed (a blind cast's descent)
    max_speed_m_s: float | None = None  # no faster than this (a profile's resolution)


@dataclass(frozen=True, slots=True)
class StopWinch:
    reason: str


@dataclass(frozen=True, slots=True)
class ReportDepth:
    depth_m: float
    phase: Phase


@dataclass(frozen=True, slots=True)
class SendFinished:
    depth_m: float
    outcome: Outcome
    reason: str | None
    last_phase: Phase  # the phase that brought the probe home (its last sample's)


@dataclass(frozen=True, slots=True)
class PhaseChanged:
    old: Phase
    new: Phase
    reason: str | None


@dataclass(frozen=True, slots=True)
class Alarm:
    message: str


Action = CommandWinch | StopWinch | ReportDepth | SendFinished | PhaseChanged | Alarm

_ALLOWED: dict[Phase, frozenset[Phase]] = {
    Phase.SOAKING: frozenset({Phase.DESCENDING, Phase.ASCENDING, Phase.ABORTING}),
    Phase.DESCENDING: frozenset({Phase.DWELLING, Phase.ASCENDING, Phase.ABORTING}),
    Phase.DWELLING: frozenset({Phase.DESCENDING, Phase.ASCENDING, Phase.ABORTING}),
    Phase.ASCENDING: frozenset({Phase.FINISHED, Phase.ABORTING}),
    Phase.ABORTING: frozenset({Phase.FINISHED, Phase.STRANDED}),
    Phase.STRANDED: frozenset({Phase.FINISHED}),
    Phase.FINISHED: frozenset(),
}
_HOME_LEGS = (Phase.ASCENDING, Phase.ABORTING)


class CastMachine:
    """One cast, from the acknowledgement to the probe being home."""

    def __init__(
        self,
        plan: CastPlan,
        *,
        started_at: float,
        report_period_s: float,
        max_duration_s: float,
        home_timeout_s: float | None = None,
    ) -> None:
        if report_period_s <= 0:
            raise ValueError("report_period_s must be > 0")
        self.plan = plan
        self.started_at = started_at
        self.report_period_s = report_period_s
        self.max_duration_s = max_duration_s
        self.home_timeout_s = max_duration_s if home_timeout_s is None else home_timeout_s
        self.phase: Phase = plan.legs[0].phase if plan.legs else Phase.STRANDED
        self.depth_m = 0.0
        self.reached_depth_m = 0.0
        self.abort_reason: str | None = None
        self.winch_fault: str | None = None
        self.bottom_contact_m: float | None = None
        self._legs: list[Leg] = list(plan.legs)
        self._commanded = False  # the current Move leg's command has been issued
        self._hold_until: float | None = None
        self._deadline = started_at + max_duration_s
        self._next_report = started_at + report_period_s

    @classmethod
    def recovery(
        cls, *, started_at: float, report_period_s: float, home_timeout_s: float, reason: str
    ) -> CastMachine:
        """Bring home a probe found down with no cast running: the abort leg alone.

        It reports depth like any cast, finishes (R-F) once the probe is home and
        strands, loudly, if it cannot get there within `home_timeout_s`.
        """
        plan = CastPlan(
            depth_m=0.0,
            limited_by="target",
            water_depth_m=None,
            mode="recovery",
            legs=(Move(0.0, Phase.ABORTING),),
        )
        machine = cls(
            plan,
            started_at=started_at,
            report_period_s=report_period_s,
            max_duration_s=home_timeout_s,
        )
        machine.abort_reason = reason
        return machine

    @classmethod
    def refused(
        cls, *, started_at: float, report_period_s: float, depth_m: float, fault: str
    ) -> CastMachine:
        """A station the winch cannot serve (its homing failed, a fault with the
        probe not verified home): no cast at all, the fault reported at once and
        every period; it ends (R-F) only when the winch reports a verified home."""
        plan = CastPlan(
            depth_m=0.0, limited_by="target", water_depth_m=None, mode="refused", legs=()
        )
        machine = cls(
            plan,
            started_at=started_at,
            report_period_s=report_period_s,
            max_duration_s=math.inf,
        )
        machine.phase = Phase.STRANDED
        machine.depth_m = depth_m
        machine.winch_fault = fault
        machine.abort_reason = f"cast refused: {fault}"
        machine._next_report = started_at  # the first fault report at once
        return machine

    # ------------------------------------------------------------ queries

    @property
    def finished(self) -> bool:
        return self.phase is Phase.FINISHED

    @property
    def outcome(self) -> Outcome:
        if not self.finished:
            return Outcome.UNFINISHED
        return Outcome.ABORTED if self.abort_reason else Outcome.COMPLETED

    def next_deadline(self) -> float:
        """The latest time `step` must be called again (reports, holds, time limits)."""
        deadline = min(self._next_report, self._deadline)
        if self._hold_until is not None:
            deadline = min(deadline, self._hold_until)
        return deadline

    # ------------------------------------------------------------ inputs

    def step(self, now: float, status: WinchStatus) -> list[Action]:
        """Advance to `now` given the winch's current `status`."""
        out: list[Action] = []
        if self.phase is Phase.FINISHED:
            return out
        self.depth_m = status.depth_m
        self.reached_depth_m = max(self.reached_depth_m, status.depth_m)
        if status.fault is not None:
            self.winch_fault = status.fault
        if self.phase is Phase.STRANDED:
            if verified_home(status):
                self._finish(out, status)
                return out
        elif now >= self._deadline:
            if self.phase is Phase.ABORTING:
                self._strand(out, f"probe not home {self.home_timeout_s:g} s after the abort")
            else:
                self._abort(out, now, f"cast exceeded max_duration_s ({self.max_duration_s:g} s)")
        elif status.fault is not None and not status.moving:
            self._fault(out, now, status.fault)
        else:
            self._advance(out, now, status)
        if not self.finished and now >= self._next_report:
            out.append(ReportDepth(self.depth_m, self.phase))
            if self.phase is Phase.STRANDED:
                out.append(Alarm(self._stranded_message()))
            periods = math.floor((now - self.started_at) / self.report_period_s) + 1
            self._next_report = self.started_at + periods * self.report_period_s
        return out

    def abort(self, now: float, reason: str) -> list[Action]:
        """Bring the probe home now (shutdown, a backend exception). Idempotent."""
        out: list[Action] = []
        if self.phase in (Phase.ABORTING, Phase.STRANDED, Phase.FINISHED):
            return out
        self._abort(out, now, reason)
        return out

    def operator_release(self, reason: str) -> list[Action]:
        """An operator who has seen the probe on board ends a stranded station
        (a broken witness: the winch can never verify home). STRANDED only."""
        out: list[Action] = []
        if self.phase is not Phase.STRANDED:
            return out
        self.abort_reason = f"released by an operator: {reason}"
        out.append(StopWinch("operator release"))
        self._enter(out, Phase.FINISHED, self.abort_reason)
        out.append(SendFinished(0.0, self.outcome, self.abort_reason, Phase.STRANDED))
        return out

    def bottom_contact(self, now: float, depth_m: float) -> list[Action]:
        """The probe touched bottom while paying out: stop there and go on with the
        cast from there (the legs below are dropped; the bottom dwell and the
        ascent remain). Ignored outside a descent. Idempotent."""
        out: list[Action] = []
        descending = [i for i, leg in enumerate(self._legs) if leg.phase is Phase.DESCENDING]
        if self.phase is not Phase.DESCENDING or not descending:
            return out
        out.append(StopWinch(f"bottom contact at {depth_m:.2f} m"))
        del self._legs[: descending[-1] + 1]
        self.bottom_contact_m = depth_m
        self._commanded = False
        self._hold_until = None
        return out

    def winch_error(self, now: float, reason: str) -> list[Action]:
        """The backend raised while carrying out a command: treat it as a fault."""
        out: list[Action] = []
        self.winch_fault = reason
        if self.phase not in (Phase.STRANDED, Phase.FINISHED):
            self._fault(out, now, reason)
        return out

    # ------------------------------------------------------------ internals

    def _enter(self, out: list[Action], new: Phase, reason: str | None = None) -> None:
        if new is self.phase:
            return
        if new not in _ALLOWED[self.phase]:
            raise TransitionError(f"cast cannot go from {self.phase} to {new}")
        out.append(PhaseChanged(self.phase, new, reason))
        self.phase = new

    def _advance(self, out: list[Action], now: float, status: WinchStatus) -> None:
        while self._legs:
            leg = self._legs[0]
            self._enter(out, leg.phase)
            if isinstance(leg, Move):
                if not self._commanded:
                    self._commanded = True
                    out.append(CommandWinch(leg.depth_m, leg.slow, leg.max_speed_m_s))
                    return  # the status in hand predates the command
                if status.moving:
                    return
                if leg.depth_m == 0.0 and not verified_home(status):
                    self._fault(out, now, f"winch stopped at {status.depth_m:.2f} m, not home")
                    return
                if leg.phase in _HOME_LEGS:
                    self._finish(out, status)
                    return
                self._commanded = False
            else:
                if self._hold_until is None:
                    self._hold_until = now + leg.seconds
                if now < self._hold_until:
                    return
                self._hold_until = None
            self._legs.pop(0)

    def _fault(self, out: list[Action], now: float, reason: str) -> None:
        if self.phase is Phase.ABORTING:
            self._strand(out, reason)
        else:
            self._abort(out, now, f"winch fault: {reason}")

    def _abort(self, out: list[Action], now: float, reason: str) -> None:
        self.abort_reason = reason
        out.append(StopWinch(reason))
        self._enter(out, Phase.ABORTING, reason)
        self._legs = [Move(0.0, Phase.ABORTING)]
        self._commanded = False
        self._hold_until = None
        self._deadline = now + self.home_timeout_s
        out.append(CommandWinch(0.0))
        self._commanded = True

    def _strand(self, out: list[Action], reason: str) -> None:
        self.abort_reason = self.abort_reason or reason
        self.winch_fault = reason
        out.append(StopWinch(reason))
        self._enter(out, Phase.STRANDED, reason)
        self._legs = []
        self._commanded = False
        self._hold_until = None
        self._deadline = math.inf
        out.append(Alarm(self._stranded_message()))

    def _stranded_message(self) -> str:
        return (
            f"PROBE NOT HOME: stuck at {self.depth_m:.2f} m ({self.winch_fault}); "
            "no R-F will be sent; the winch motor is stopped; operator intervention needed"
        )

    def _finish(self, out: list[Action], status: WinchStatus) -> None:
        if not verified_home(status):  # the rule the autopilot's safety rests on
            raise TransitionError("refusing to finish a cast while the probe is not home")
        out.append(StopWinch("probe home"))
        last_phase = self.phase
        self._enter(out, Phase.FINISHED, self.abort_reason)
        self._legs = []
        out.append(SendFinished(status.depth_m, self.outcome, self.abort_reason, last_phase))
