"""An adversary's cases against the GPIO winch's two witnesses, its dead-encoder
estimate and its sensor rules (a review of issue 19's work): each failed before the
fix it names. MockFactory pins and the project's simulated drum."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

import pytest

from cc_daemon.config import load_settings
from cc_daemon.core.errors import ConfigError, WinchFault
from cc_daemon.drivers.winch.motor import Direction
from cc_daemon.sim.drum import DrumFaults
from tests.gpiokit import enable_history, gpio_rig

MPP = 3.141592653589793 * 0.09 / 2  # metres of line per pulse with the kit's drum


async def _until(condition: Callable[[], bool], timeout: float = 10.0) -> None:
    async with asyncio.timeout(timeout):
        while not condition():  # noqa: ASYNC110  (the mock drum's thread sets it)
            await asyncio.sleep(0.005)


async def test_a_switch_that_shorts_after_a_dead_encoder_verdict_does_not_verify_home() -> None:
    # The count is no witness once the encoder is dead: a switch that closes with no
    # haul running (a short, a snag on the lever) is one witness, not home, no R-F.
    async with gpio_rig(adc=True) as rig:
        rig.drum.encoder_dead = True  # the pulse wire cut at home, before the cast
        rig.winch.move_to(2.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("encoder dead")
        # Down and clear of the block: how far depends on how soon the silence was
        # judged (at least stall_timeout_s of a running motor), never less than a pulse.
        assert rig.drum.line_m > MPP and status.depth_m > MPP
        rig.drum.faults.switch_stuck_closed = True
        await rig.until(lambda: rig.winch.switch_closed)
        seen = await rig.quiet(0.6)  # past switch_settle_s: its verdict is in
        assert not any(s.at_home for s in seen)
        status = seen[-1]
        assert status.fault is not None and "one witness cannot verify home" in status.fault


async def test_a_current_sensor_stuck_at_its_top_mid_descent_does_not_strand_the_probe() -> None:
    # The overcurrent stop, then the abort's haul home at once: the haul waits out the
    # 20 ms a winding needs, so the zero check finds the sensor and the pulses guard it.
    async with gpio_rig(adc=True) as rig:
        rig.winch.move_to(5.0)
        await _until(lambda: rig.drum.line_m > 1.5)
        rig.drum.faults.current_adc = 1.0
        await rig.settle()
        first = rig.winch.status()
        assert first.fault is not None and "above max_current_a" in first.fault
        rig.winch.move_to(0.0)  # what the cast machine's abort does, in the same turn
        await rig.settle()
        assert rig.winch.sensor_fault is not None
        assert rig.winch.status().at_home


async def test_dead_reckoning_never_says_0_m_with_the_switch_open() -> None:
    # R-P 0 says home; only two witnesses may say that.
    async with gpio_rig(adc=True, faults=DrumFaults(encoder_dead_in_from_m=0.2)) as rig:
        rig.winch.move_to(0.45)
        await rig.settle()
        rig.drum.full_speed_m_s *= 0.4  # a heavy probe: the drum hauls slower than set
        rig.winch.move_to(0.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("encoder dead")
        assert not rig.winch.switch_closed and rig.drum.line_m > 0.1
        assert status.depth_m >= MPP


async def test_after_a_pulse_storm_a_short_hand_haul_moves_the_estimate() -> None:
    async with gpio_rig(adc=True, faults=DrumFaults(storm_at_m=1.0)) as rig:
        rig.winch.move_to(3.0)
        await rig.settle()
        assert rig.winch.distrust is not None and "encoder fault" in rig.winch.distrust
        estimate = rig.winch.depth_estimate
        assert estimate is not None and estimate.low_m <= rig.drum.line_m <= estimate.high_m
        start = rig.drum.line_m
        rig.winch.jog(Direction.HAUL_IN)  # the operator's P-U, released before a stall
        await _until(lambda: rig.drum.line_m < start - 0.3)
        rig.winch.jog(Direction.STOPPED)
        await rig.settle()
        estimate = rig.winch.depth_estimate
        assert estimate is not None and estimate.low_m <= rig.drum.line_m <= estimate.high_m
        assert abs(rig.winch.status().depth_m - rig.drum.line_m) < 0.3


async def test_after_an_idle_storm_at_home_a_haul_says_it_cannot_verify_home() -> None:
    async with gpio_rig() as rig:
        rig.drum.faults.storm_at_m = 0.0  # interference on the pulse wire, the winch idle
        await _until(lambda: rig.winch.distrust is not None)
        rig.drum.faults.storm_at_m = None
        with pytest.raises(WinchFault, match="cc-daemon release"):
            rig.winch.hand_move(0.0)  # `cc-daemon winch home` through the daemon, or P-U
        assert rig.drum.motor() == (0, 0.0)


async def test_a_haul_at_the_block_does_not_pull_against_it() -> None:
    # Both witnesses at home: the operator's P-U runs no motor into the block.
    async with gpio_rig() as rig:
        assert rig.winch.status().at_home
        rig.winch.jog(Direction.HAUL_IN)
        assert rig.drum.motor() == (0, 0.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.at_home and status.fault is None


async def _worst_loop_gap(gaps: list[float]) -> None:
    """Until cancelled: the longest the event loop went without running this (a
    loaded machine's pause), kept in `gaps[0]`."""
    last = time.monotonic()
    while True:
        await asyncio.sleep(0.01)
        now = time.monotonic()
        gaps[0] = max(gaps[0], now - last - 0.01)
        last = now


async def test_the_smallest_loop_watchdog_accepted_can_run_the_motor() -> None:
    # The ticks (every 50 ms) feed the watchdog often enough at its smallest setting:
    # a whole move ends without a trip, and a trip is only ever a loop that really was
    # silent that long (a loaded machine can pause it: then the move is tried again).
    tripped: list[float] = []
    for _ in range(5):
        gaps = [0.0]
        async with gpio_rig(loop_watchdog_s=0.2) as rig:
            watching = asyncio.create_task(_worst_loop_gap(gaps))
            try:
                rig.winch.move_to(2.0)
                await rig.settle()
            finally:
                watching.cancel()
            fault = rig.winch.status().fault
        if fault is None:
            return
        assert fault.startswith("loop watchdog"), fault
        assert gaps[0] >= 0.2 - 0.05, f"tripped with the loop silent {gaps[0]:.3f} s at most"
        tripped.append(gaps[0])
    pytest.fail(f"every move tripped, the loop silent at most {tripped} s: a machine too busy")


def _refused(gpio: dict[str, Any]) -> str:
    with pytest.raises(ConfigError) as caught:
        load_settings(None, {"winch": {"gpio": gpio}}, env={}, search_paths=())
    return str(caught.value)


@pytest.mark.parametrize(
    ("gpio", "named"),
    [
        ({"loop_watchdog_s": 0.05}, "loop_watchdog_s = 0.05"),  # under the 50 ms ticks
        ({"count_tolerance_m": 1000.0}, "count_tolerance_m = 1000.0"),
        ({"adc": True, "max_current_a": 0.6}, "max_current_a = 0.6"),  # a silent drum untold
        ({"adc": True, "current_zero_v": 0.0}, "current_zero_v = 0.0"),  # 0 A at the rail
        ({"adc": True, "supply_min_v": 0.0}, "supply_min_v = 0.0"),  # a dead channel passes
        ({"pulse_debounce_s": 0.5}, "pulse_debounce_s = 0.5"),  # loses pulses at speed
    ],
    ids=["watchdog", "tolerance", "max-current", "zero-at-rail", "supply-min-0", "debounce"],
)
def test_settings_that_can_never_work_exit_2_naming_the_key(
    gpio: dict[str, Any], named: str
) -> None:
    assert f"winch.gpio.{named}" in _refused(gpio)


async def test_a_stop_while_a_start_waits_for_the_zero_leaves_the_motor_off() -> None:
    # A move replacing a running one waits 20 ms before it starts; a stop (a signal's
    # shutdown, the watchdog's fault path, close) in that window must cancel it.
    async with gpio_rig(adc=True) as rig:
        rig.winch.move_to(3.0)
        await _until(lambda: rig.drum.motor()[0] == 1)
        rig.winch.move_to(0.5)  # replaces the running move: its start waits
        assert rig.winch.status().moving and rig.drum.motor() == (0, 0.0)
        rig.winch.stop()
        seen = await rig.quiet(0.1)  # past the 20 ms: the start, had it stayed, ran
        assert rig.drum.motor() == (0, 0.0) and not seen[-1].moving


async def test_a_switch_closing_while_a_haul_waits_for_the_zero_keeps_the_motor_off() -> None:
    # The haul's start waits 20 ms; a switch edge in that window stopped no motor
    # (none ran). Had the haul been running, the edge would have stopped it: it must
    # not start into the block, pulling until the stall rule (a review found it did).
    async with gpio_rig() as rig:
        rig.winch.move_to(3.0)
        await _until(lambda: rig.drum.line_m > 0.3)
        switch = rig.drum.factory.pin(rig.winch._cfg.switch_pin)
        rig.drum.close()  # the test drives the switch: the edge surely inside the window
        rig.winch.move_to(0.0)  # an abort: replaces a running move, its start waits
        assert rig.winch._pending is not None
        waits_from = time.monotonic()
        switch.drive_high()  # the edge, inside the window
        seen = await rig.quiet(0.2)  # past the 20 ms: the start, had it stayed, ran
        assert not any(duty > 0 for t, duty in enable_history(rig) if t >= waits_from)
        status = seen[-1]  # the edge judged as ever (here: within tolerance)
        assert not status.moving and (status.fault is None or "stall" not in status.fault)


async def test_a_delayed_start_that_fails_is_a_fault_not_a_lost_error() -> None:
    # Not delayed, a start that raises reaches whoever asked (the cast, the jog).
    # Delayed, no one is waiting: it must be the winch's fault, the motor off.
    async with gpio_rig() as rig:
        rig.winch.move_to(3.0)
        await _until(lambda: rig.drum.motor()[0] == 1)
        rig.winch.move_to(0.5)
        assert rig.winch._pending is not None

        def broken(*_: object) -> None:
            raise OSError("the H-bridge's pins are gone")

        rig.winch._bridge.start = broken  # type: ignore[method-assign]
        await _until(lambda: rig.winch.status().fault is not None, 2.0)
        fault = rig.winch.status().fault
        assert fault is not None and "could not be started" in fault and "pins are gone" in fault
        assert rig.drum.motor() == (0, 0.0) and not rig.winch.status().moving
