"""The GPIO winch on gpiozero's MockFactory, driven by a simulated drum: motions and safety.

Every assertion is on what the pins did (the PWM enable pin's state history),
where the simulated drum's line really is, the winch's status, and the events
it journaled.
"""

from __future__ import annotations

import asyncio
import subprocess
import sys
import textwrap
import time

import pytest
import structlog

from cc_daemon.core.errors import WinchFault
from cc_daemon.core.winch.status import ApproachSpeed
from cc_daemon.drivers.winch.motor import Direction
from cc_daemon.sim.drum import DrumFaults
from tests.gpiokit import REPO, enable_history, gpio_rig

MPP = 3.141592653589793 * 0.09 / 2  # metres of line per pulse with the kit's drum


async def test_a_move_ramps_up_slows_near_the_target_and_stops_within_half_a_pulse() -> None:
    async with gpio_rig() as rig:
        assert rig.winch.status().at_home and rig.winch.homed
        rig.enable_pin.clear_states()
        rig.winch.move_to(2.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is None and not status.moving
        assert abs(status.depth_m - 2.0) <= MPP / 2
        assert abs(rig.drum.line_m - 2.0) <= MPP / 2 + 0.02  # the drum, not just the count
        duties = [duty for _, duty in enable_history(rig)]
        assert duties[-1] == 0.0
        running = duties[1:-1]
        assert running[0] == pytest.approx(0.9 * 0.3)  # the soft start's first step
        assert max(running) == pytest.approx(0.9)
        assert running[-1] == pytest.approx(0.45)  # the approach: half power
        assert rig.winch.overshoots == [0] or rig.winch.overshoots[0] <= 1


async def test_a_slow_move_runs_at_the_approach_duty_from_start_to_end() -> None:
    # A blind cast's descent (core.winch.status ApproachSpeed): never above the
    # approach duty, the soft start within it, and it still arrives on the count.
    async with gpio_rig() as rig:
        assert isinstance(rig.winch, ApproachSpeed)
        rig.enable_pin.clear_states()
        rig.winch.move_slowly_to(1.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is None and abs(status.depth_m - 1.0) <= MPP / 2
        running = [duty for _, duty in enable_history(rig)][1:-1]
        assert running[0] == pytest.approx(0.45 * 0.3)  # the soft start, from the cap
        assert max(running) == pytest.approx(0.45)  # payout_duty 0.9 x the approach fraction
        rig.enable_pin.clear_states()
        rig.winch.move_to(2.0)  # the flag lasts one motion: the next runs at full duty
        await rig.settle()
        assert max(duty for _, duty in enable_history(rig)) == pytest.approx(0.9)


async def test_a_cast_comes_home_at_the_switch_and_the_count_is_zero() -> None:
    async with gpio_rig() as rig:
        rig.winch.move_to(1.5)
        await rig.settle()
        rig.winch.move_to(0.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.at_home and status.depth_m == 0.0 and status.fault is None
        assert rig.winch.pulse_count == 0
        assert rig.drum.line_m <= MPP / 4
        assert "winch_count_corrected" not in rig.kinds()


async def test_a_switch_to_ground_and_a_pulled_up_sensor_work_the_same() -> None:
    async with gpio_rig(switch_pull="up", switch_active="low", pulse_pull="up") as rig:
        assert rig.winch.status().at_home
        rig.winch.move_to(1.0)
        await rig.settle()
        assert abs(rig.winch.status().depth_m - 1.0) <= MPP / 2
        rig.winch.move_to(0.0)
        await rig.settle()
        assert rig.winch.status().at_home and rig.winch.pulse_count == 0


async def test_quadrature_encoder_counts_both_ways() -> None:
    async with gpio_rig(counter="quadrature") as rig:
        rig.winch.move_to(1.2)
        await rig.settle()
        assert abs(rig.winch.status().depth_m - 1.2) <= MPP / 2
        rig.winch.move_to(0.5)
        await rig.settle()
        assert abs(rig.winch.status().depth_m - 0.5) <= MPP / 2
        assert abs(rig.drum.line_m - 0.5) <= MPP
        rig.winch.move_to(0.0)
        await rig.settle()
        assert rig.winch.status().at_home and rig.winch.pulse_count == 0


async def test_never_pays_out_beyond_the_end_of_the_line() -> None:
    async with gpio_rig(max_line_m=1.0) as rig:
        rig.winch.move_to(5.0)  # clamped to the line's end
        await rig.settle()
        assert rig.winch.status().depth_m <= 1.0 + MPP / 2
        rig.winch.jog(Direction.PAY_OUT)  # by hand, the end of the line still holds
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("end of line")
        # The motor is stopped at the first pulse counted past the line's end ...
        stopped_at = rig.winch.pulse_count
        assert 1.0 <= stopped_at * MPP <= 1.0 + MPP
        # ... and what the drum turns after it is the edge callback's latency (a busy
        # machine took 15 mm once): less than another pulse, which would be counted.
        assert rig.drum.max_line_seen < (stopped_at + 1) * MPP
        assert rig.winch.pulse_count == stopped_at
        assert enable_history(rig)[-1][1] == 0.0


async def test_a_drum_thread_that_ran_late_turns_no_further_than_the_motor_drove_it() -> None:
    # Under load the simulated drum's thread made up a long pause in one step, past the
    # pulse at which the winch had stopped the motor: 1.155 m out of a 1.0 m line.
    async with gpio_rig(max_line_m=1.0, stall_timeout_s=10.0) as rig:
        rig.winch.jog(Direction.PAY_OUT)
        await rig.until(lambda: rig.drum.line_m > 0.5)
        rig.drum.close()  # the drum's thread stops; the motor runs on, unseen ...
        paused = time.monotonic()
        await rig.until(lambda: time.monotonic() - paused > 1.0)  # ... past the line's end
        rig.drum.catch_up()  # ... and the pause is made up at once, as a late thread does
        assert rig.drum.motor() == (0, 0.0)  # stopped at the end of the line's pulse
        assert rig.drum.max_line_seen <= 1.0 + MPP


async def test_a_jammed_drum_is_a_stall_and_the_motor_goes_off() -> None:
    async with gpio_rig(faults=DrumFaults(jam_at_m=0.8)) as rig:
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("stall: no drum pulse")
        assert enable_history(rig)[-1][1] == 0.0
        assert rig.drum.motor() == (0, 0.0)
        assert ("winch_fault", pytest.approx) and rig.kinds().count("winch_fault") == 1


async def test_overcurrent_for_longer_than_allowed_is_a_stall() -> None:
    async with gpio_rig(adc=True, faults=DrumFaults(overcurrent_a=4.2)) as rig:
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and "motor current" in status.fault
        assert rig.drum.motor() == (0, 0.0)
        detail = dict(rig.events)["winch_fault"]
        assert detail["peak_current_a"] == pytest.approx(4.2, abs=0.05)


async def test_current_and_supply_are_read_through_the_mcp3008() -> None:
    async with gpio_rig(adc=True) as rig:
        assert rig.winch.motor_current_a() == pytest.approx(0.0, abs=0.02)
        assert rig.winch.supply_v() == pytest.approx(12.0, abs=0.1)
        rig.winch.jog(Direction.PAY_OUT)
        await rig.until(lambda: rig.drum.motor() == (1, 0.9))  # the soft start done
        assert rig.winch.motor_current_a() == pytest.approx(1.2 * 0.9, abs=0.05)
        rig.winch.stop()


async def test_haul_home_gives_up_when_the_switch_never_closes() -> None:
    # A tolerance wider than the haul: the deadline, not the witnesses, ends it.
    async with gpio_rig(count_tolerance_m=5.0) as rig:
        rig.winch.move_to(0.6)
        await rig.settle()
        rig.drum.faults.switch_stuck_open = True  # the drum winds on past the block
        started = time.monotonic()
        rig.winch.move_to(0.0)
        await rig.settle()
        took = time.monotonic() - started
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("home not reached")
        # line out / speed + home_margin_s: 0.6 / 1.0 + 1.0, never sooner (a deadline
        # cannot expire early; how late a loaded machine ends it is no rule's)
        assert took >= 1.5
        assert rig.drum.motor() == (0, 0.0)


async def test_the_switch_closing_while_paying_out_stops_and_faults() -> None:
    async with gpio_rig(faults=DrumFaults(snag_at_m=1.0)) as rig:
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and "closed while paying out" in status.fault
        assert 0.9 <= rig.drum.line_m <= 1.0 + MPP
        assert rig.drum.motor() == (0, 0.0)


async def test_lost_pulses_are_corrected_at_the_switch_with_both_figures() -> None:
    # Drift within count_tolerance_m is corrected at a believed switch; beyond it the
    # witnesses disagree (tests/test_gpio_witnesses.py). This test used to pin the old
    # rule "the switch always zeroes the count", the very bug of the two-witness issue.
    async with gpio_rig(faults=DrumFaults(lose_every=4), count_tolerance_m=1.5) as rig:
        rig.winch.move_to(3.0)
        await rig.settle()
        real = rig.drum.line_m
        assert real > 3.5  # the count lost a pulse in four: the probe went deeper
        with structlog.testing.capture_logs() as logs:
            rig.winch.move_to(0.0)
            await rig.settle()
        assert rig.winch.status().at_home and rig.winch.pulse_count == 0
        # Hauling in, the count reaches home first: it says so, and hauls on.
        early = next(e for e in logs if "disagree" in e["event"] and e["switch"] == "open")
        assert early["counted_line_m"] <= 0.0
        corrected = next(e for e in logs if "count corrected" in e["event"])
        assert corrected["switch"] == "closed" and corrected["counted_line_m"] < -0.2
        recorded = dict(rig.events)["winch_count_corrected"]
        assert recorded["counted_line_m"] == corrected["counted_line_m"]
        assert recorded["corrected_to_m"] == 0.0


async def test_start_up_homing_hauls_a_probe_left_down() -> None:
    async with gpio_rig(line_m=1.3) as rig:
        status = rig.winch.status()
        assert status.at_home and status.fault is None and rig.winch.homed
        assert rig.kinds()[:2] == ["winch_homing", "winch_homed"]
        assert rig.drum.line_m <= MPP / 4


async def test_without_start_up_homing_casts_are_refused_until_homed_by_hand() -> None:
    async with gpio_rig(line_m=1.3, home_at_start=False) as rig:
        status = rig.winch.status()
        assert not status.at_home and status.fault is not None
        assert status.fault.startswith("not homed")
        with pytest.raises(WinchFault, match="not homed"):
            rig.winch.move_to(2.0)
        assert rig.drum.motor() == (0, 0.0)
        rig.winch.jog(Direction.HAUL_IN)  # the operator, with `cc-daemon winch home`
        await rig.settle()
        assert rig.winch.homed and rig.winch.status().at_home
        rig.winch.move_to(0.5)
        await rig.settle()
        assert abs(rig.winch.status().depth_m - 0.5) <= MPP / 2


async def test_the_loop_watchdog_stops_the_motor_when_the_loop_blocks() -> None:
    async with gpio_rig(loop_watchdog_s=0.5) as rig:
        rig.winch.jog(Direction.PAY_OUT)
        await rig.until(lambda: rig.drum.motor()[0] == 1)
        blocked_at = time.monotonic()
        # The point: the event loop is stuck, until the watchdog's thread has stopped the
        # motor (how soon after loop_watchdog_s: benchmarks/winch.py, docs/performance.md).
        while rig.drum.motor()[0] != 0 and time.monotonic() - blocked_at < 30:
            time.sleep(0.01)  # noqa: ASYNC251
        off_at = next(t for t, duty in enable_history(rig) if t > blocked_at and duty == 0.0)
        assert off_at - blocked_at >= 0.5 - 0.1  # not before the loop was silent that long
        await asyncio.sleep(0)  # the loop runs again and hears about it
        await asyncio.sleep(0)
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("loop watchdog")
        assert "winch_fault" in rig.kinds()


async def test_an_exception_in_a_check_stops_the_motor(monkeypatch: pytest.MonkeyPatch) -> None:
    async with gpio_rig() as rig:

        def broken(now: float) -> None:
            raise OSError("PWM chip gone")

        # Was motor_current_a raising: the tick reads the current through the
        # sensing helper now, which the zero check before a move may disable.
        monkeypatch.setattr(rig.winch, "_set_power", broken)
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and "PWM chip gone" in status.fault
        assert rig.drum.motor() == (0, 0.0)


async def test_close_and_cancellation_leave_the_motor_off() -> None:
    async with gpio_rig() as rig:

        async def lower() -> None:
            rig.winch.move_to(5.0)
            try:
                await asyncio.sleep(10)
            finally:
                rig.winch.stop()

        task = asyncio.create_task(lower())
        await rig.until(lambda: rig.drum.motor()[0] == 1)
        cancelled_at = time.monotonic()
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        off_at, duty = enable_history(rig)[-1]
        # Off by the cancelled task's own stop, not later by a watchdog (no fault).
        assert duty == 0.0 and off_at >= cancelled_at and rig.winch.status().fault is None
        rig.winch.jog(Direction.PAY_OUT)
    assert rig.drum.motor() == (0, 0.0)  # closed while running: off


def test_the_motor_is_switched_off_at_interpreter_exit() -> None:
    script = textwrap.dedent(
        """
        import asyncio, atexit
        from tests.gpiokit import settings
        from cc_daemon.ground.clock import SystemClock
        from cc_daemon.drivers.winch.devices import open_devices
        from cc_daemon.drivers.winch.gpio import GpioWinch
        from cc_daemon.sim.drum import SimulatedDrum
        from cc_daemon.drivers.winch.motor import Direction

        cfg = settings()
        factory = SimulatedDrum.factory_for(cfg)
        drum = SimulatedDrum(factory, cfg)
        atexit.register(lambda: print("at exit", drum.motor(), flush=True))

        async def main():
            winch = GpioWinch(cfg, open_devices(cfg, factory), max_line_m=20, clock=SystemClock())
            winch.jog(Direction.PAY_OUT)
            print("running", drum.motor(), flush=True)
            return winch  # never closed: the process just ends

        keep = asyncio.run(main())
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script],
        check=False,
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 0, done.stderr
    assert "running (1, " in done.stdout
    assert "at exit (0, 0.0)" in done.stdout


async def test_the_switch_bouncing_as_the_probe_leaves_is_not_a_snag() -> None:
    async with gpio_rig() as rig:
        switch = rig.drum.factory.pin(rig.winch._cfg.switch_pin)
        rig.drum.close()  # the test moves the pins by hand now
        rig.winch.jog(Direction.PAY_OUT)
        switch.drive_low()  # the probe leaves the block...
        switch.drive_high()  # ...the lever bounces shut...
        switch.drive_low()  # ...and open again, all within the first pulse
        await asyncio.sleep(0)  # one turn of the loop: the three edges heard
        status = rig.winch.status()
        assert status.moving and status.fault is None
        rig.winch.stop()


async def test_the_probe_slipping_off_the_block_while_idle_is_logged() -> None:
    async with gpio_rig() as rig:
        switch = rig.drum.factory.pin(rig.winch._cfg.switch_pin)
        rig.drum.close()
        with structlog.testing.capture_logs() as logs:
            switch.drive_low()
            switch.drive_high()  # a bounce: not news
            await rig.quiet(0.2)  # its check (SWITCH_SETTLE_S) found the switch closed again
            switch.drive_low()  # it stays open
            await rig.until(lambda: any("opened with" in e["event"] for e in logs))
            await rig.quiet(0.2)  # and nothing more comes of it
        slipped = [e for e in logs if "opened with the motor stopped" in e["event"]]
        assert len(slipped) == 1 and slipped[0]["log_level"] == "warning"
        assert not rig.winch.status().at_home


async def test_homing_a_probe_already_home_says_so_and_times_itself() -> None:
    # `cc-daemon winch home` at home logged "hauling in" and took_s = the machine's
    # uptime: no motion started, so the motion's start time was never set.
    async with gpio_rig() as rig:
        started = time.monotonic()
        with structlog.testing.capture_logs() as logs:
            assert await rig.winch.home()
        took = time.monotonic() - started
        assert not any(e["log_level"] == "warning" for e in logs)
        assert any("already closed" in e["event"] for e in logs)
        [homed] = [e for e in logs if e["event"] == "winch homed"]
        assert 0.0 <= homed["took_s"] <= took + 0.005  # the settle time, not the uptime
        assert rig.drum.max_line_seen == 0.0


async def test_homing_a_probe_down_times_the_haul() -> None:
    async with gpio_rig() as rig:
        rig.winch.move_to(1.0)
        await rig.settle()
        started = time.monotonic()
        with structlog.testing.capture_logs() as logs:
            assert await rig.winch.home()
        took = time.monotonic() - started
        [homed] = [e for e in logs if e["event"] == "winch homed"]
        # The haul's own time (logged to 0.01 s): 1 m at about 1 m/s at least, and
        # within what the test saw.
        assert 0.9 <= homed["took_s"] <= took + 0.005
