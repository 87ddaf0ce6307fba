"""Test kit for the pure cast core: settings, stations, and a fake-time driver.

`drive` plays the role of the asyncio shell: it steps the machine at each
moment something can change (a report deadline, a hold ending, the winch
arriving), carries out its actions on `LinePhysics`, and records what would
have gone over the link. No real time passes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from cc_daemon.config import Settings
from cc_daemon.core.cast.machine import (
    Action,
    Alarm,
    CastMachine,
    CommandWinch,
    PhaseChanged,
    ReportDepth,
    SendFinished,
    StopWinch,
)
from cc_daemon.core.cast.plan import CastPlan, plan_cast
from cc_daemon.core.protocol import StartMeasuring
from cc_daemon.core.winch.physics import LinePhysics

MADRID_LAT_E7 = 404506308
MADRID_LON_E7 = -37260579


def settings(**cast: Any) -> Settings:
    return Settings.model_validate({"cast": cast})


def station(
    sonar_mm: int = 8219,
    confidence: int = 100,
    lat_e7: int = MADRID_LAT_E7,
    lon_e7: int = MADRID_LON_E7,
) -> StartMeasuring:
    return StartMeasuring(72, lon_e7, lat_e7, 702385, sonar_mm, confidence)


@dataclass
class Run:
    """What a driven cast did, as the link and the winch saw it."""

    reports: list[tuple[float, float, str]] = field(default_factory=list)  # time, depth, phase
    finished: list[tuple[float, SendFinished]] = field(default_factory=list)
    alarms: list[tuple[float, str]] = field(default_factory=list)
    phases: list[tuple[float, str]] = field(default_factory=list)
    commands: list[tuple[float, float]] = field(default_factory=list)
    stops: list[tuple[float, str]] = field(default_factory=list)
    home_at_finish: list[bool] = field(default_factory=list)
    steps: int = 0


def execute(
    machine: CastMachine, physics: LinePhysics, actions: list[Action], now: float, run: Run
) -> bool:
    commanded = False
    for action in actions:
        match action:
            case CommandWinch(depth_m=depth, max_speed_m_s=limit):
                # A profile's limit is obeyed; a blind cast's approach speed is not
                # (the tests of a blind cast reason at the line's one speed).
                physics.command(now, depth, max_speed_m_s=limit)
                run.commands.append((now, depth))
                commanded = True
            case StopWinch(reason=reason):
                physics.stop(now)
                run.stops.append((now, reason))
            case ReportDepth(depth_m=depth, phase=phase):
                run.reports.append((now, depth, str(phase)))
            case SendFinished():
                run.finished.append((now, action))
                run.home_at_finish.append(physics.status(now).at_home)
            case PhaseChanged(new=new):
                run.phases.append((now, str(new)))
            case Alarm(message=message):
                run.alarms.append((now, message))
    return commanded


def drive(
    plan: CastPlan,
    physics: LinePhysics,
    *,
    start: float = 1000.0,
    period: float = 1.0,
    max_duration: float = 600.0,
    until: float | None = None,
    abort_at: float | None = None,
) -> tuple[CastMachine, Run]:
    machine = CastMachine(
        plan, started_at=start, report_period_s=period, max_duration_s=max_duration
    )
    run = Run()
    now = start
    limit = until if until is not None else start + 10 * max_duration
    while not machine.finished and now <= limit:
        if abort_at is not None and now >= abort_at:
            execute(machine, physics, machine.abort(now, "shutdown"), now, run)
            abort_at = None
        commanded = execute(machine, physics, machine.step(now, physics.status(now)), now, run)
        run.steps += 1
        if machine.finished or commanded:
            continue
        wake = machine.next_deadline()
        arrival = physics.arrival_time(now)
        if arrival is not None:
            wake = min(wake, arrival)
        if abort_at is not None:
            wake = min(wake, abort_at)
        now = max(wake, now)
    return machine, run


def plan_for(st: StartMeasuring, s: Settings) -> CastPlan:
    plan = plan_cast(st, s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan), plan
    return plan
