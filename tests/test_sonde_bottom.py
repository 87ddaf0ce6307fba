"""Depth cross-check and bottom contact on fake time: monitor, cast machine and winch physics."""

from __future__ import annotations

import random

import pytest

from cc_daemon.core.cast.machine import CastMachine, Outcome, SendFinished
from cc_daemon.core.cast.plan import Phase
from cc_daemon.core.winch.physics import LinePhysics
from cc_daemon.drivers.sonde.depthcheck import (
    BottomContact,
    DepthAgreement,
    DepthDisagreement,
    DepthMonitor,
)
from cc_daemon.sim.water import SondeModel, WaterColumn
from tests.castkit import Run, execute, plan_for, settings, station


def monitor() -> DepthMonitor:
    return DepthMonitor(disagreement_m=1.0, contact_s=5.0, tolerance_m=0.05)


def test_disagreement_is_reported_once_per_episode_with_hysteresis() -> None:
    m = monitor()
    events = [
        m.feed(t, line, sonde, paying_out=False)
        for t, line, sonde in [
            (0, 2.0, 1.9),
            (1, 3.0, 1.9),  # 1.1 m apart: disagreement
            (2, 3.2, 2.0),  # still: no repeat
            (3, 3.0, 2.1),  # 0.9 m: within the threshold but not within 80 %
            (4, 3.0, 2.3),  # 0.7 m: agreement
        ]
    ]
    assert events == [
        [],
        [DepthDisagreement(3.0, 1.9)],
        [],
        [],
        [DepthAgreement(3.0, 2.3)],
    ]


def test_missing_sonde_depth_decides_nothing() -> None:
    m = monitor()
    assert m.feed(0, 1.0, 1.0, paying_out=True) == []
    for t in range(1, 20):
        assert m.feed(t, 1.0 + t, None, paying_out=True) == []
    assert m.contact is None


def test_contact_needs_the_line_going_out_while_the_sonde_stays() -> None:
    m = monitor()
    # The winch holding (line still): a still sonde is no contact.
    for t in range(10):
        assert m.feed(t, 3.0, 3.0, paying_out=True) == []
    m.reset()
    # Line out growing while the sonde stays at 3 m: contact once, after 5 s.
    got = [m.feed(t, 3.0 + 0.25 * t, 3.0, paying_out=True) for t in range(12)]
    assert [t for t, ev in enumerate(got) if ev and isinstance(ev[-1], BottomContact)] == [5]
    assert m.contact == BottomContact(3.0, 4.25, 5.0)


def test_descending_normally_is_no_contact() -> None:
    m = monitor()
    for t in range(40):
        assert m.feed(t, 0.25 * t, 0.25 * t * 0.99, paying_out=True) == []


def drive_with_sonde(bottom_m: float, target_m: float) -> tuple[CastMachine, Run, list[object]]:
    # No sonar: the sonde is the only guard; a blind cast allowed as deep as the target.
    s = settings(target_depth_m=target_m, bottom_dwell_s=5.0, blind_max_depth_m=target_m)
    plan = plan_for(station(confidence=0), s)
    physics = LinePhysics(speed_m_s=0.25, max_line_m=20.0)
    model = SondeModel(WaterColumn(bottom_m=bottom_m), slant_deg=0.0, rng=random.Random(1))
    m = monitor()
    start = 1000.0
    machine = CastMachine(plan, started_at=start, report_period_s=1.0, max_duration_s=600.0)
    run = Run()
    events: list[object] = []
    now = start
    while not machine.finished and now < start + 600:
        execute(machine, physics, machine.step(now, physics.status(now)), now, run)
        if (now - start) % 1.0 == 0:  # the sonde's 1 s samples
            status = physics.status(now)
            reading = model.read(status.depth_m, now)
            paying_out = machine.phase is Phase.DESCENDING and status.moving
            for event in m.feed(now, status.depth_m, reading["depth"], paying_out=paying_out):
                events.append(event)
                if isinstance(event, BottomContact):
                    execute(
                        machine, physics, machine.bottom_contact(now, event.sonde_depth_m), now, run
                    )
        now += 0.25
    return machine, run, events


def test_bottom_contact_stops_the_descent_and_the_cast_goes_on() -> None:
    machine, run, events = drive_with_sonde(bottom_m=3.0, target_m=8.0)
    contact = next(e for e in events if isinstance(e, BottomContact))
    assert contact.sonde_depth_m == pytest.approx(3.0, abs=0.05)
    # Stopped about bottom_contact_s after touching: 3 m + 5 s x 0.25 m/s of slack at most.
    stop_time, _reason = next((t, r) for t, r in run.stops if r.startswith("bottom contact"))
    deepest = max(depth for _, depth, _ in run.reports)
    assert 3.0 < deepest <= 3.0 + 0.25 * 6 + 0.01
    assert machine.reached_depth_m < 8.0
    assert machine.bottom_contact_m == contact.sonde_depth_m
    # Then the bottom dwell, the ascent and R-F with the probe home, as a completed cast.
    phases = [p for _, p in run.phases]
    assert phases[-3:] == ["dwelling", "ascending", "finished"]
    (_, finished), *_ = run.finished
    assert isinstance(finished, SendFinished) and finished.outcome is Outcome.COMPLETED
    assert run.home_at_finish == [True]
    assert any(isinstance(e, DepthDisagreement) for e in events)  # the slack line shows too
    assert stop_time > 1000.0


def test_no_contact_in_deep_water() -> None:
    machine, _run, events = drive_with_sonde(bottom_m=30.0, target_m=5.0)
    assert not any(isinstance(e, BottomContact) for e in events)
    assert machine.bottom_contact_m is None
    assert machine.reached_depth_m == pytest.approx(5.0)
    assert machine.outcome is Outcome.COMPLETED


def test_bottom_contact_outside_a_descent_is_ignored() -> None:
    plan = plan_for(station(confidence=0), settings(target_depth_m=5.0))
    machine = CastMachine(plan, started_at=0.0, report_period_s=1.0, max_duration_s=600.0)
    physics = LinePhysics(speed_m_s=0.25, max_line_m=20.0)
    execute(machine, physics, machine.step(0.0, physics.status(0.0)), 0.0, Run())
    assert machine.phase is Phase.DESCENDING
    assert len(machine.bottom_contact(1.0, 0.25)) == 1
    assert machine.bottom_contact(2.0, 0.25) == []  # idempotent: the descent is gone
    execute(machine, physics, machine.step(2.0, physics.status(2.0)), 2.0, Run())
    assert machine.phase is Phase.DWELLING
    assert machine.bottom_contact(3.0, 0.25) == []
