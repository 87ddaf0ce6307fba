"""An arrival the loop hears late must not stop the haul home that replaced it.

gpiozero's thread stops the motor on the pulse that reaches a target and hands
the news to the loop (`edges._tell_loop`). A loop busy at that moment (a loaded
Pi) may meanwhile abort the cast (a shutdown, the stick, `max_duration_s`) and
command the haul home; the late news must not then halt that haul: the winch
would stand still, short of home, with no fault, and the cast would strand a
healthy probe (R-L, an operator called out, exit 130 at a shutdown).

The loop is held here (a busy loop, as under load) from the command until the
drum's thread has stopped the motor, so the news is certainly still on its way.
Real gpiozero devices on MockFactory, the simulated drum turning from the pins.
"""

from __future__ import annotations

import time

from cc_daemon.core.cast.machine import CastMachine, CommandWinch, SendFinished, StopWinch
from cc_daemon.core.cast.plan import CastPlan, Phase, plan_cast
from cc_daemon.drivers.winch.gpio import GpioWinch
from cc_daemon.drivers.winch.motor import Direction
from tests.castkit import settings, station
from tests.gpiokit import gpio_rig

# The loop held longer than this would trip the winch's watchdog: the most it allows.
WATCHDOG_S = 5.0
TARGET_M = 0.3  # two pulses of the kit's drum: reached at the soft start's floor


def hold_loop_until_the_thread_stops(winch: GpioWinch) -> None:
    """Block the event loop (as a busy one would) until gpiozero's thread has stopped
    the motor at the target; the loop has not heard of it yet."""
    deadline = time.monotonic() + WATCHDOG_S * 0.8
    while winch._bridge.direction is not Direction.STOPPED:
        assert time.monotonic() < deadline, "the drum never reached the target"
        time.sleep(0.001)
    status = winch.status()
    assert status.moving, "the stop is in flight: the status still says moving"


async def test_a_haul_home_commanded_before_the_loop_hears_the_arrival_runs() -> None:
    async with gpio_rig(loop_watchdog_s=WATCHDOG_S) as rig:
        rig.winch.move_to(TARGET_M)
        hold_loop_until_the_thread_stops(rig.winch)
        rig.winch.move_to(0.0)  # the abort's haul home
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is None
        assert status.at_home, f"the haul home was stopped by a late arrival: {status}"
        assert rig.drum.line_m < 0.05


async def test_a_cast_aborted_as_it_arrives_brings_the_probe_home_and_finishes() -> None:
    s = settings(target_depth_m=TARGET_M, min_depth_m=0.1, bottom_dwell_s=0.0)
    plan = plan_cast(station(sonar_mm=30_000), s.cast, s.winch.max_line_m)
    assert isinstance(plan, CastPlan) and plan.depth_m == TARGET_M
    async with gpio_rig(loop_watchdog_s=WATCHDOG_S) as rig:
        winch = rig.winch

        def carry(actions: list[object]) -> list[SendFinished]:
            finished = []
            for action in actions:
                if isinstance(action, CommandWinch):
                    winch.move_to(action.depth_m)
                elif isinstance(action, StopWinch):
                    winch.stop()
                elif isinstance(action, SendFinished):
                    finished.append(action)
            return finished

        machine = CastMachine(
            plan, started_at=time.monotonic(), report_period_s=1.0, max_duration_s=600.0
        )
        carry(machine.step(time.monotonic(), winch.status()))  # the descent commanded
        hold_loop_until_the_thread_stops(winch)
        assert machine.phase is Phase.DESCENDING
        carry(machine.abort(time.monotonic(), "shutdown"))  # SIGTERM, the stick, a time-out
        finished: list[SendFinished] = []
        deadline = time.monotonic() + 30.0
        while not machine.finished and machine.phase is not Phase.STRANDED:
            assert time.monotonic() < deadline
            finished += carry(machine.step(time.monotonic(), winch.status()))
            await winch.wait_change(0.05)
        assert machine.phase is Phase.FINISHED, (
            f"stranded a healthy probe: {machine.winch_fault} (drum at {rig.drum.line_m:.2f} m)"
        )
        assert [f.reason for f in finished] == ["shutdown"] and winch.status().at_home
