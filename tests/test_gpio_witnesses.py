"""Home has two witnesses: the line count and the limit switch, on gpiozero's MockFactory.

One faulty sensor (a switch stuck closed, a snag, a short closure, a switch stuck
open) must never declare the probe home: the motor stops, the fault names both
figures, `move_to` is refused, and only an operator's haul that brings both
witnesses into agreement clears it.
"""

from __future__ import annotations

import asyncio
import sys
from typing import Any

import pytest
import structlog

from cc_daemon.config import Settings
from cc_daemon.core.errors import WinchFault
from cc_daemon.core.winch.encoder import RATE_WINDOW, EncoderJudge
from cc_daemon.core.winch.sensors import current_fault
from cc_daemon.core.winch.status import HOMING_FAILED, refuses_casts, verified_home
from cc_daemon.core.winch.witness import LEAVE_PULSES, Witnesses
from cc_daemon.drivers.winch.gpio import GIL_SWITCH_S
from cc_daemon.drivers.winch.motor import Direction
from cc_daemon.sim.drum import DrumFaults, mock_drum_for
from tests.gpiokit import gpio_rig

MPP = 3.141592653589793 * 0.09 / 2  # metres of line per pulse with the kit's drum


# ---------------------------------------------------------------- the pure rules


def test_the_witnesses_disagree_in_three_ways() -> None:
    w = Witnesses(tolerance_m=0.5, settle_s=0.2, leave_m=0.4)
    assert w.disagreement(0.2, True, 0) is None
    closed_out = w.disagreement(3.96, True, 0)
    assert closed_out is not None and "3.96 m" in closed_out
    never_left = w.disagreement(0.45, True, +1)
    assert never_left is not None and "never left the block" in never_left
    assert w.disagreement(0.45, True, -1) is None
    past_zero = w.disagreement(-0.6, False, -1)
    assert past_zero is not None and "0.60 m past" in past_zero
    assert w.disagreement(-0.6, False, 0) is None  # coasting: not a haul


# ---------------------------------------------------------------- on mock pins


async def test_a_switch_stuck_closed_stops_the_descent_and_never_says_home() -> None:
    async with gpio_rig(faults=DrumFaults(switch_stuck_closed=True)) as rig:
        assert rig.winch.status().at_home  # both agree at start: count 0, switch closed
        rig.winch.move_to(3.96)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and "never left the block" in status.fault
        assert not status.at_home and rig.drum.motor() == (0, 0.0)
        # Stopped within the first few pulses, not at 3.96 m.
        assert rig.drum.line_m <= (LEAVE_PULSES + 1) * MPP
        fault = dict(rig.events)["winch_fault"]
        assert fault["switch_closed"] is True and fault["counted_line_m"] > 0
        with pytest.raises(WinchFault, match="witnesses disagree"):
            rig.winch.move_to(0.0)
        # The operator hauls in: the count reaches zero with the switch closed.
        rig.winch.jog(Direction.HAUL_IN)
        await rig.settle()
        status = rig.winch.status()
        assert status.at_home and status.fault is None
        assert rig.drum.line_m <= MPP
        assert "winch_home_verified" in rig.kinds()


async def test_a_snag_closing_the_switch_mid_descent_keeps_the_count() -> None:
    async with gpio_rig(faults=DrumFaults(snag_at_m=1.0)) as rig:
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and "closed while paying out" in status.fault
        # The count is not reset: the probe is still 1 m down, and not "home".
        assert not status.at_home
        assert abs(status.depth_m - rig.drum.line_m) <= MPP
        assert status.depth_m > 0.9
        assert rig.drum.motor() == (0, 0.0)
        # It stays so for longer than the settle time, switch closed or not.
        assert not any(s.at_home for s in await rig.quiet(0.4))


async def test_a_short_closure_at_depth_is_never_home() -> None:
    async with gpio_rig() as rig:
        rig.winch.move_to(2.0)
        await rig.settle()
        switch = rig.drum.factory.pin(rig.winch._cfg.switch_pin)
        rig.drum.close()  # the test moves the pins by hand now
        switch.drive_high()  # a closure at 2 m, as short as the pins allow
        switch.drive_low()
        assert not any(s.at_home for s in await rig.quiet(0.5))
        assert rig.winch.status().fault is not None
        assert "closed with 1.98 m counted" in (rig.winch.status().fault or "")


async def test_a_short_closure_near_home_is_not_home_until_it_settles() -> None:
    async with gpio_rig(switch_settle_s=0.3) as rig:
        rig.winch.move_to(0.2)  # one pulse out, within the tolerance
        await rig.settle()
        switch = rig.drum.factory.pin(rig.winch._cfg.switch_pin)
        rig.drum.close()
        switch.drive_high()
        switch.drive_low()  # a blip: not home
        assert not any(s.at_home for s in await rig.quiet(0.4))
        switch.drive_high()  # held: home once settled, the small drift corrected
        # One turn of the loop: the edge heard, its 0.3 s settle started, and this
        # look in the same turn (no timer can fire between them).
        await asyncio.sleep(0)
        assert not rig.winch.status().at_home and rig.winch.status().moving
        await rig.until(lambda: rig.winch.status().at_home)
        assert rig.winch.pulse_count == 0
        assert "winch_count_corrected" in rig.kinds()


async def test_hauling_in_with_the_switch_stuck_open_stops_short_of_the_block() -> None:
    async with gpio_rig(count_tolerance_m=0.3) as rig:
        rig.winch.move_to(2.0)
        await rig.settle()
        rig.drum.faults.switch_stuck_open = True
        rig.winch.move_to(0.0)
        await rig.settle()
        status = rig.winch.status()
        # Stopped one tolerance past zero (plus a pulse) by the witnesses, not by the
        # home deadline (that fault says "home not reached").
        assert status.fault is not None and "past the count's zero" in status.fault
        assert not status.at_home
        assert -0.3 - 2 * MPP <= rig.drum.line_m <= 0.0
        assert rig.drum.motor() == (0, 0.0)


async def test_a_failed_start_up_homing_says_so_in_the_words_mains_rules_read() -> None:
    # The daemon's rules (core.winch.status) refuse casts and R-F on a winch whose
    # start-up homing failed, by the fault's first words: the GPIO winch must use them.
    faults = DrumFaults(switch_stuck_open=True)
    # Homing from an unknown position allows the whole line: 1 m keeps it short.
    async with gpio_rig(line_m=0.6, faults=faults, max_line_m=1.0) as rig:
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith(HOMING_FAILED + ": ")
        assert "home not reached" in status.fault  # what stopped the haul, kept
        assert refuses_casts(status) and not verified_home(status)
        assert ("winch_fault", {"fault": status.fault}) in rig.events
        assert rig.drum.motor() == (0, 0.0)
        # The switch mended, an operator's haul brings both witnesses into agreement.
        faults.switch_stuck_open = False
        rig.winch.jog(Direction.HAUL_IN)
        await rig.settle()
        # Home once the switch has stayed closed for its settle time (0.2 s).
        await rig.until(lambda: verified_home(rig.winch.status()))
        status = rig.winch.status()
        assert status.fault is None and verified_home(status) and not refuses_casts(status)


# ---------------------------------------------------------------- the encoder


def test_the_encoder_judge_knows_a_coasting_drum_from_a_storm() -> None:
    judge = EncoderJudge(max_pulses_s=8.0, coast_pulses=3)
    assert [judge.pulse(t, False) for t in (0.0, 0.1, 0.2)] == [None] * 3
    coast = judge.pulse(0.3, False)
    assert coast is not None and "4 pulses with the motor off" in coast
    judge.motor_started()
    # Running at full speed (8/s) and at 2.9 times it: the drum.
    assert all(judge.pulse(i / 8.0, True) is None for i in range(20))
    judge.motor_started()
    assert all(judge.pulse(i / 23.0, True) is None for i in range(20))
    judge.motor_started()
    storm = [judge.pulse(i / 50_000, True) for i in range(5)]
    assert storm[:4] == [None] * 4 and storm[4] is not None and "faster than" in storm[4]


async def test_an_idle_pulse_storm_is_an_encoder_fault_not_7068_m() -> None:
    async with gpio_rig() as rig:
        pulse = rig.drum.factory.pin(rig.winch._cfg.pulse_pin)
        rig.drum.close()  # the test drives the pins now: 2000 pulses, the motor off
        for _ in range(2000):
            pulse.drive_high()
            pulse.drive_low()
        await rig.until(lambda: rig.winch.status().fault is not None)
        status = rig.winch.status()
        assert status.fault is not None and "encoder fault" in status.fault
        assert "with the motor off" in status.fault
        assert not status.at_home
        assert rig.winch.line_m <= 0.5  # counted up to the coasting allowance, no more
        assert rig.kinds().count("winch_fault") == 1
        with pytest.raises(WinchFault, match="encoder fault"):
            rig.winch.move_to(2.0)
        # The switch is closed: nothing could stop a haul, and it could verify nothing.
        with pytest.raises(WinchFault, match=r"hauling in refused.*cc-daemon release"):
            rig.winch.jog(Direction.HAUL_IN)
        assert rig.drum.motor() == (0, 0.0)


async def test_a_pulse_storm_mid_descent_stops_the_motor() -> None:
    async with gpio_rig() as rig:
        pulse = rig.drum.factory.pin(rig.winch._cfg.pulse_pin)
        rig.winch.move_to(3.0)
        await rig.until(lambda: rig.winch.status().depth_m > 0.2)  # well under way
        with structlog.testing.capture_logs() as logs:
            for _ in range(3000):
                pulse.drive_high()
                pulse.drive_low()
            await rig.settle()

            def told() -> list[Any]:
                return [e for e in logs if e["event"] == "winch encoder fault: pulses not counted"]

            # The pulses not counted are summarised a while after the storm.
            await rig.until(lambda: sum(e["pulses"] for e in told()) > 2900)
        status = rig.winch.status()
        assert status.fault is not None and "faster than the drum can turn" in status.fault
        assert rig.drum.motor() == (0, 0.0)
        assert status.depth_m < 3.0  # not the kilometres the storm would count
        assert 1 <= len(told()) <= 2


async def test_the_winch_shortens_the_switch_interval_while_open_and_restores_it() -> None:
    # A storm on gpiozero's thread must not hold the GIL for the default 5 ms
    # (docs/gpio-winch.md "The pulse storm").
    before = sys.getswitchinterval()
    async with gpio_rig():
        assert sys.getswitchinterval() == pytest.approx(GIL_SWITCH_S)
    assert sys.getswitchinterval() == before


# ---------------------------------------------------------------- the current sensor


def test_current_readings_that_cannot_be_true() -> None:
    assert current_fault(1.0, 4.3, motor_on=False) is not None  # at the top rail at rest
    # Running, the top rail may be a jam past the sensor's range: the overcurrent rule's.
    assert current_fault(1.0, 4.3, motor_on=True) is None
    assert current_fault(0.0, -13.5, motor_on=True) is not None  # the bottom rail: never
    assert current_fault(0.0, -13.5, motor_on=False) is not None  # at the bottom rail
    off = current_fault(0.87, 2.0, motor_on=False)
    assert off is not None and "with the motor off" in off
    assert current_fault(0.87, 2.0, motor_on=True) is None  # running: 2 A is a motor
    assert current_fault(0.76, 0.02, motor_on=False) is None


@pytest.mark.parametrize("adc", [1.0, 0.87], ids=["stuck-full-scale", "2-amps-at-rest"])
async def test_a_faulty_current_sensor_is_found_at_rest_and_said_once(adc: float) -> None:
    async with gpio_rig(adc=True, faults=DrumFaults(current_adc=adc)) as rig:
        rig.winch.move_to(1.0)  # the zero check before the move finds it
        await rig.settle()
        status = rig.winch.status()
        # Not a 0.5 s "overcurrent stall": the move arrives, guarded by the pulses.
        assert status.fault is None and abs(status.depth_m - 1.0) <= MPP / 2
        assert rig.winch.sensor_fault is not None
        rig.winch.move_to(0.0)
        await rig.settle()
        assert rig.winch.status().at_home
        assert rig.kinds().count("winch_sensor_fault") == 1
        [event] = [d for k, d in rig.events if k == "winch_sensor_fault"]
        assert event["fallback"] == "stall-by-pulses"


async def test_a_jam_is_still_a_stall_once_the_current_sensor_is_faulty() -> None:
    faults = DrumFaults(current_adc=1.0, jam_at_m=0.8)
    async with gpio_rig(adc=True, faults=faults) as rig:
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("stall: no drum pulse")
        assert rig.drum.motor() == (0, 0.0)


async def test_a_current_sensor_that_cannot_be_read_does_not_refuse_the_move(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    async with gpio_rig(adc=True) as rig:

        def gone(*, motor_on: bool) -> float:
            raise OSError("SPI bus gone")

        monkeypatch.setattr(rig.winch._sensing, "current_a", gone)
        rig.winch.move_to(0.5)
        monkeypatch.undo()
        await rig.settle()
        assert rig.winch.status().fault is None
        assert "SPI bus gone" in (rig.winch.sensor_fault or "")


async def _running(rig: Any) -> None:
    """Until the probe is well clear of the block, the motor still paying out."""
    async with asyncio.timeout(30):
        while rig.winch.status().depth_m < 0.5:  # status() re-arms wait_change
            await rig.winch.wait_change(0.05)
    assert rig.winch._bridge.direction is Direction.PAY_OUT


def _storm_now(rig: Any) -> None:
    """Pulses faster than any drum, on this thread, as gpiozero's thread would call
    them: the edge side stops the motor and tells the loop, which has not run yet."""
    for _ in range(RATE_WINDOW + 1):
        rig.winch._pulse_thread()
    assert rig.winch._encoder_bad is not None


async def test_a_stop_made_on_the_pin_thread_is_still_moving_until_the_loop_hears_why() -> None:
    # Under load the loop can read the status between the edge thread's stop and its
    # own handling of it: "stopped, no fault" short of the target read as an arrival.
    async with gpio_rig() as rig:
        rig.winch.move_to(3.0)
        await _running(rig)
        _storm_now(rig)
        assert rig.drum.motor() == (0, 0.0)  # stopped at once, on the edge's thread
        before = rig.winch.status()
        assert before.moving or before.fault is not None, before
        await rig.settle()
        after = rig.winch.status()
        assert after.fault is not None and "encoder fault" in after.fault


async def test_what_the_pin_thread_told_a_closed_winch_is_dropped() -> None:
    # A verdict still on its way to the loop when the winch closes would touch closed
    # pins (GPIODeviceClosed in the loop's exception handler, seen under load).
    errors: list[dict[str, Any]] = []
    loop = asyncio.get_running_loop()
    loop.set_exception_handler(lambda _loop, context: errors.append(context))
    try:
        async with gpio_rig() as rig:
            rig.winch.move_to(3.0)
            await _running(rig)
            _storm_now(rig)
            await rig.winch.close()  # no await inside: the verdict is still queued
            await asyncio.sleep(0)  # ... and now it runs
            await asyncio.sleep(0)
    finally:
        loop.set_exception_handler(None)
    assert errors == []


async def test_the_mock_drums_pulse_storm_is_an_encoder_fault_where_it_starts() -> None:
    async with gpio_rig(faults=DrumFaults(storm_at_m=1.0)) as rig:
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and "encoder fault" in status.fault
        assert 1.0 <= status.depth_m <= 1.5  # counted to where the storm began, no further
        assert rig.drum.motor() == (0, 0.0)
        with pytest.raises(WinchFault, match="encoder fault"):
            rig.winch.move_to(0.0)


@pytest.mark.parametrize(
    ("name", "fault"),
    [
        ("switch-stuck", {"switch_stuck_closed": True}),
        ("snag", {"snag_at_m": 1.0}),
        ("adc-garbage", {"current_adc": 1.0}),
        ("pulse-storm", {"storm_at_m": 1.0}),
    ],
)
def test_each_winch_sim_drum_fault_reaches_the_mock_drum(name: str, fault: dict[str, Any]) -> None:
    settings = Settings.model_validate(
        {
            "winch": {
                "backend": "gpio",
                "gpio": {"pin_factory": "mock"},
                "sim": {"drum_fault": name},
            }
        }
    )
    drum = mock_drum_for(settings)
    try:
        assert drum.faults == DrumFaults(**fault)
    finally:
        drum.close()
        drum.factory.reset()
