"""The cast state machine on fake time, against the pure winch physics."""

from __future__ import annotations

import time

import pytest
from hypothesis import given
from hypothesis import settings as hyp_settings
from hypothesis import strategies as st

from cc_daemon.core.cast.machine import CastMachine, Outcome, ReportDepth
from cc_daemon.core.cast.plan import Phase
from cc_daemon.core.errors import TransitionError
from cc_daemon.core.winch.physics import HOME_TOLERANCE_M, LinePhysics
from cc_daemon.core.winch.status import HOMING_FAILED, WinchStatus
from tests.castkit import drive, plan_for, settings, station

START = 1000.0


def physics(speed: float = 0.25, **faults: object) -> LinePhysics:
    return LinePhysics(speed_m_s=speed, max_line_m=20.0, **faults)  # type: ignore[arg-type]


def test_a_whole_continuous_cast() -> None:
    s = settings(target_depth_m=5.0, bottom_dwell_s=10.0)
    machine, run = drive(plan_for(station(sonar_mm=30_000), s), physics(), start=START)
    # 20 s down at 0.25 m/s, 10 s dwell, 20 s up.
    assert machine.finished and machine.outcome is Outcome.COMPLETED
    assert len(run.finished) == 1
    when, finished = run.finished[0]
    assert when == pytest.approx(START + 50.0)
    assert finished.depth_m == 0.0 and finished.reason is None
    assert run.home_at_finish == [True]
    # One report a second on absolute deadlines, from the ack until home.
    times = [t for t, _, _ in run.reports]
    assert times == [START + k for k in range(1, 50)]
    depths = [d for _, d, _ in run.reports]
    deepest = depths.index(max(depths))
    assert max(depths) == pytest.approx(5.0)
    assert depths[:deepest] == sorted(depths[:deepest])
    assert depths[deepest:] == sorted(depths[deepest:], reverse=True)
    assert [p for _, p in run.phases] == ["dwelling", "ascending", "finished"]
    assert machine.reached_depth_m == pytest.approx(5.0)


def test_late_steps_send_one_report_and_keep_the_schedule() -> None:
    s = settings()
    machine = CastMachine(
        plan_for(station(), s), started_at=START, report_period_s=1.0, max_duration_s=600
    )
    idle = WinchStatus(0.0, True, True, None)
    machine.step(START, idle)
    late = machine.step(START + 3.7, WinchStatus(0.9, True, False, None))
    assert [a for a in late if isinstance(a, ReportDepth)] == [ReportDepth(0.9, Phase.DESCENDING)]
    assert machine.next_deadline() == START + 4.0


def test_stepped_cast_dwells_at_each_level() -> None:
    s = settings(mode="stepped", step_m=1.0, dwell_s=3.0, target_depth_m=3.0)
    machine, run = drive(plan_for(station(sonar_mm=30_000), s), physics(speed=0.5), start=START)
    assert machine.outcome is Outcome.COMPLETED
    dwell_depths = sorted({round(d, 3) for _, d, p in run.reports if p == "dwelling"})
    assert dwell_depths == [1.0, 2.0, 3.0]


def test_a_stall_aborts_and_brings_the_probe_home_before_r_f() -> None:
    s = settings(target_depth_m=5.0)
    machine, run = drive(
        plan_for(station(sonar_mm=30_000), s), physics(stall_at_m=2.0), start=START
    )
    assert machine.outcome is Outcome.ABORTED
    assert "stall" in (machine.abort_reason or "")
    assert run.home_at_finish == [True]
    assert max(d for _, d, _ in run.reports) == pytest.approx(2.0)
    assert "aborting" in [p for _, p in run.phases]
    # the stall happened at 8 s, then 8 s back up
    assert run.finished[0][0] == pytest.approx(START + 16.0)


def test_a_probe_that_cannot_come_home_is_stranded_loudly_and_never_finished() -> None:
    s = settings(target_depth_m=3.0, bottom_dwell_s=1.0)
    phys = physics(fail_home=True)
    machine, run = drive(
        plan_for(station(sonar_mm=30_000), s), phys, start=START, until=START + 120
    )
    assert machine.phase is Phase.STRANDED
    assert run.finished == []
    assert not phys.status(START + 120).moving  # the motor is stopped
    stranded_at = next(t for t, p in run.phases if p == "stranded")
    later = [(t, d) for t, d, _ in run.reports if t > stranded_at]
    assert len(later) >= 60
    assert {round(d, 3) for _, d in later} == {0.5}  # the last known depth, every period
    assert len([t for t, _ in run.alarms if t > stranded_at]) >= len(later)
    assert all("PROBE NOT HOME" in m for _, m in run.alarms)
    # An operator hauls the probe in: the limit switch closes, R-F goes out.
    phys.fail_home = False
    phys.command(START + 121, 0.0)
    home = phys.arrival_time(START + 121)
    assert home is not None
    actions = machine.step(home, phys.status(home))
    assert machine.finished and machine.outcome is Outcome.ABORTED
    assert any(type(a).__name__ == "SendFinished" for a in actions)


def test_max_duration_aborts_the_cast() -> None:
    s = settings(target_depth_m=5.0, bottom_dwell_s=100.0)
    machine, run = drive(
        plan_for(station(sonar_mm=30_000), s), physics(), start=START, max_duration=60.0
    )
    assert machine.outcome is Outcome.ABORTED
    assert "max_duration_s" in (machine.abort_reason or "")
    assert run.home_at_finish == [True]
    assert run.finished[0][0] == pytest.approx(START + 60.0 + 20.0)


def test_shutdown_mid_cast_brings_the_probe_home_then_finishes() -> None:
    s = settings(target_depth_m=5.0)
    machine, run = drive(
        plan_for(station(sonar_mm=30_000), s), physics(), start=START, abort_at=START + 10.0
    )
    assert machine.outcome is Outcome.ABORTED and machine.abort_reason == "shutdown"
    assert run.finished[0][0] == pytest.approx(START + 20.0)
    assert run.home_at_finish == [True]


def test_abort_is_idempotent_and_ignored_once_finished() -> None:
    s = settings()
    machine, _ = drive(plan_for(station(sonar_mm=30_000), s), physics(speed=5.0), start=START)
    assert machine.finished
    assert machine.abort(START + 1000, "late") == []


def test_a_winch_that_stops_short_of_home_without_a_fault_is_a_fault() -> None:
    s = settings(target_depth_m=1.0, bottom_dwell_s=0.0)
    machine = CastMachine(
        plan_for(station(sonar_mm=30_000), s),
        started_at=START,
        report_period_s=1,
        max_duration_s=600,
    )
    machine.step(START, WinchStatus(0.0, False, True, None))  # command 1.0 m
    machine.step(START + 4, WinchStatus(1.0, False, False, None))  # arrived, dwell 0, command home
    actions = machine.step(START + 5, WinchStatus(0.6, False, False, None))  # stopped short
    assert machine.phase is Phase.ABORTING
    assert "not home" in (machine.abort_reason or "")
    assert any(type(a).__name__ == "CommandWinch" for a in actions)


def test_finishing_while_not_home_is_refused() -> None:
    s = settings()
    machine = CastMachine(
        plan_for(station(sonar_mm=30_000), s),
        started_at=START,
        report_period_s=1,
        max_duration_s=600,
    )
    with pytest.raises(TransitionError):
        machine._finish([], WinchStatus(2.0, False, False, None))


def test_finishing_needs_home_verified_as_r_f_does_everywhere() -> None:
    # core.winch.status.verified_home: a switch made on a winch whose homing
    # failed, or one still moving, vouches for nothing.
    machine = CastMachine(
        plan_for(station(sonar_mm=30_000), settings(target_depth_m=1.0, bottom_dwell_s=0.0)),
        started_at=START,
        report_period_s=1,
        max_duration_s=600,
    )
    machine.step(START, WinchStatus(0.0, False, True, None))  # command 1.0 m
    machine.step(START + 4, WinchStatus(1.0, False, False, None))  # arrived: command home
    assert machine.phase is Phase.ASCENDING
    with pytest.raises(TransitionError):
        machine._finish([], WinchStatus(0.0, False, True, f"{HOMING_FAILED}: stall"))
    with pytest.raises(TransitionError):
        machine._finish([], WinchStatus(0.0, True, True, None))
    machine._finish([], WinchStatus(0.0, False, True, None))
    assert machine.phase is Phase.FINISHED


def test_illegal_transitions_raise() -> None:
    s = settings()
    machine = CastMachine(
        plan_for(station(sonar_mm=30_000), s),
        started_at=START,
        report_period_s=1,
        max_duration_s=600,
    )
    with pytest.raises(TransitionError):
        machine._enter([], Phase.STRANDED)  # only an abort can strand a cast


def test_an_hour_of_casts_runs_in_well_under_a_second() -> None:
    s = settings(target_depth_m=4.0, bottom_dwell_s=5.0)
    plan = plan_for(station(sonar_mm=30_000), s)
    began = time.perf_counter()
    now, casts = START, 0
    while now < START + 3600:
        machine, run = drive(plan, physics(), start=now)
        assert machine.outcome is Outcome.COMPLETED and len(run.finished) == 1
        now = run.finished[0][0] + 30.0  # transit to the next station
        casts += 1
    assert casts >= 50
    assert time.perf_counter() - began < 5.0  # generous: a guard against a real-time wait


@hyp_settings(max_examples=150, deadline=None)
@given(
    target=st.floats(0.3, 15.0),
    speed=st.floats(0.05, 2.0),
    mode=st.sampled_from(["continuous", "stepped"]),
    stall=st.one_of(st.none(), st.floats(0.1, 14.0)),
    fail_home=st.booleans(),
    abort_after=st.one_of(st.none(), st.floats(0.0, 200.0)),
    period=st.sampled_from([0.5, 1.0, 2.0]),
)
def test_safety_invariants_hold_for_any_cast(
    target: float,
    speed: float,
    mode: str,
    stall: float | None,
    fail_home: bool,
    abort_after: float | None,
    period: float,
) -> None:
    s = settings(target_depth_m=target, mode=mode, step_m=2.0, dwell_s=2.0, bottom_dwell_s=3.0)
    phys = physics(speed=speed, stall_at_m=stall, fail_home=fail_home)
    abort_at = None if abort_after is None else START + abort_after
    machine, run = drive(
        plan_for(station(sonar_mm=30_000), s),
        phys,
        start=START,
        period=period,
        max_duration=600,
        abort_at=abort_at,
        until=START + 2000,
    )
    # R-F at most once, and only with the probe home.
    assert len(run.finished) <= 1
    assert all(run.home_at_finish)
    # Either the cast finished or the probe is stranded; never anything else.
    assert machine.finished or machine.phase is Phase.STRANDED
    if fail_home and machine.reached_depth_m > HOME_TOLERANCE_M:
        assert not machine.finished  # it went down and can never come home
    # The motor is never left running.
    assert not phys.status(START + 2000).moving
    # Reports sit on absolute deadlines.
    for t, _, _ in run.reports:
        k = (t - START) / period
        assert k == pytest.approx(round(k), abs=1e-6)


def test_a_refused_station_reports_the_fault_at_once_and_ends_only_at_a_verified_home() -> None:
    from cc_daemon.core.cast.machine import SendFinished
    from cc_daemon.core.winch.status import refuses_casts, verified_home

    failed = WinchStatus(2.0, False, False, "homing failed: switch never closed")
    assert refuses_casts(failed) and not verified_home(failed)
    # The switch made but the homing fault standing: not a home R-F may rely on.
    stuck = WinchStatus(0.0, False, True, "homing failed: switch closed at 3.96 m")
    assert refuses_casts(stuck) and not verified_home(stuck)
    assert not refuses_casts(WinchStatus(0.0, False, True, "stall: no drum pulse"))
    assert not refuses_casts(WinchStatus(2.0, False, False, None))  # down, no fault: recovered

    machine = CastMachine.refused(started_at=10.0, report_period_s=1.0, depth_m=2.0, fault="x")
    assert machine.phase is Phase.STRANDED
    first = machine.step(10.0, failed)
    assert [a for a in first if isinstance(a, ReportDepth)] == [ReportDepth(2.0, Phase.STRANDED)]
    assert machine.step(10.5, failed) == []  # one report a period
    for t in (11.0, 12.0, 13.0):
        assert not any(isinstance(a, SendFinished) for a in machine.step(t, stuck))
    done = machine.step(14.0, WinchStatus(0.0, False, True, None))
    [finish] = [a for a in done if isinstance(a, SendFinished)]
    assert finish.outcome is Outcome.ABORTED and machine.abort_reason == "cast refused: x"
