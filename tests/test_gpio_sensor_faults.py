"""Sensors that cannot be true, said once: a motor current that steps faster than a
motor on a drum can, and a supply voltage outside its configured range.

The pure rules (`core/winch/sensors.py`), the keys that bound them (exit 2 naming
the keys), and the GPIO winch on gpiozero's MockFactory with the simulated drum's
noisy current sensor and supply override: one sensor fault, the fallback to
stall-by-pulses said once, the move finished by the pulses; a real jam read by a
sane sensor still an overcurrent stall.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Iterator, MutableMapping
from pathlib import Path
from typing import Any

import pytest
import structlog

from cc_daemon.cli.app import main
from cc_daemon.cli.status.view import status_lines
from cc_daemon.cli.winch import _line
from cc_daemon.config import load_settings
from cc_daemon.core.errors import ConfigError
from cc_daemon.core.winch.sensors import (
    current_jump_fault,
    jump_limit_a,
    supply_fault,
)
from cc_daemon.drivers.winch.devices import open_devices
from cc_daemon.drivers.winch.sensing import SUPPLY_EVERY, ZERO_SETTLE_S, MotorSensing
from cc_daemon.sim.drum import DrumFaults, SimulatedDrum
from tests.gpiokit import GpioRig, gpio_rig, settings

MPP = 3.141592653589793 * 0.09 / 2  # metres of line per pulse with the kit's drum
FALLBACK = "winch sensor fault: overcurrent protection falls back to stall-by-pulses"
PREFIX = "cc-daemon: bad configuration: "


def sensor_faults(rig: GpioRig) -> list[dict[str, Any]]:
    return [detail for kind, detail in rig.events if kind == "winch_sensor_fault"]


async def wait_for(condition: Any, timeout: float = 10.0) -> None:
    """Poll a condition on the drum's thread (no event to wait on) with a generous limit."""
    deadline = asyncio.get_running_loop().time() + timeout
    while asyncio.get_running_loop().time() < deadline:
        if condition():
            return
        await asyncio.sleep(0.02)
    raise AssertionError(f"not within {timeout} s")


# ---------------------------------------------------------------- the pure rules


def test_a_jam_is_not_a_jump_but_noise_is() -> None:
    assert jump_limit_a(4.0) == 8.0
    # Running at 0.9 duty (the mock drum's 1.2 A x 0.9) into a jam at 4x: a motor.
    assert current_jump_fault(1.08, 4.32, max_current_a=4.0) is None
    # The biggest running current the bound allows a 4x jam from: 2/3 of the limit.
    assert current_jump_fault(8 / 3, 4 * 8 / 3, max_current_a=4.0) is None
    assert current_jump_fault(4.3, 0.3, max_current_a=4.0) is None  # a snag let go
    assert current_jump_fault(-1.0, -4.0, max_current_a=4.0) is None  # hauling in, a lead sensor
    # The ACS712-5A on a 3.3 V ADC reads -13.5..4.3 A: noise steps across that span.
    noisy = current_jump_fault(-11.12, 1.59, max_current_a=4.0)
    assert noisy is not None
    assert "from -11.12 A to 1.59 A" in noisy and "step of 12.71 A" in noisy
    assert "(8 A, 2 x max_current_a)" in noisy
    assert current_jump_fault(1.0, -7.5, max_current_a=4.0) is not None  # down as well as up
    assert current_jump_fault(0.5, 1.0, max_current_a=0.2) is not None  # scales with the limit


def test_a_supply_outside_its_range_cannot_be_true() -> None:
    assert supply_fault(12.0, min_v=9.0, max_v=16.0) is None
    assert supply_fault(9.0, min_v=9.0, max_v=16.0) is None  # the bounds are in the range
    assert supply_fault(16.0, min_v=9.0, max_v=16.0) is None
    low = supply_fault(6.0, min_v=9.0, max_v=16.0)
    assert (
        low
        == "supply voltage reads 6.00 V, below supply_min_v 9 V: the supply or the ADC is faulty"
    )
    high = supply_fault(16.41, min_v=9.0, max_v=16.0)
    assert high is not None and "16.41 V, above supply_max_v 16 V" in high


# ---------------------------------------------------------------- the keys


def problems(gpio: dict[str, object]) -> list[str]:
    with pytest.raises(ConfigError) as caught:
        load_settings(None, {"winch": {"gpio": gpio}}, env={}, search_paths=())
    return [line.removeprefix(PREFIX) for line in str(caught.value).splitlines()]


def test_the_supply_range_defaults_to_a_12_v_battery() -> None:
    gpio = load_settings(None, {"winch": {"gpio": {"adc": True}}}, env={}, search_paths=()).winch
    assert (gpio.gpio.supply_min_v, gpio.gpio.supply_max_v) == (9.0, 16.0)


@pytest.mark.parametrize(
    ("gpio", "expected"),
    [
        (
            {"supply_max_v": 61},
            "winch.gpio.supply_max_v = 61 (from the command line): must be at most 60",
        ),
        (
            {"supply_min_v": -1},
            "winch.gpio.supply_min_v = -1 (from the command line): must be at least 0",
        ),
        (
            {"supply_min_v": 12, "supply_max_v": 12},
            "winch.gpio.supply_min_v = 12 (from the command line) and winch.gpio.supply_max_v "
            "= 12 (from the command line): impossible combination: winch.gpio.supply_min_v "
            "must be below winch.gpio.supply_max_v (the supply's range would be empty)",
        ),
    ],
)
def test_the_supply_range_is_bounded(gpio: dict[str, object], expected: str) -> None:
    assert problems(gpio) == [expected]


def test_a_supply_range_the_divider_cannot_read_names_the_keys() -> None:
    # 3.3 V x (29.4 k + 7.4 k) / 7.4 k = 16.41 V: a 17 V supply would read 16.41.
    assert problems({"adc": True, "supply_max_v": 17.0}) == [
        "winch.gpio.supply_max_v = 17.0 (from the command line), winch.gpio.adc_vref_v = 3.3 "
        "(default), winch.gpio.divider_r1_ohm = 29400.0 (default) and winch.gpio.divider_r2_ohm "
        "= 7400.0 (default): impossible combination: winch.gpio.supply_max_v must be below the "
        "most the divider can read, winch.gpio.adc_vref_v x (winch.gpio.divider_r1_ohm + "
        "winch.gpio.divider_r2_ohm) / winch.gpio.divider_r2_ohm = 16.41 V (a supply above it "
        "reads full scale, never above winch.gpio.supply_max_v)"
    ]
    # Without the ADC nothing reads the supply: the same range is not refused.
    load_settings(None, {"winch": {"gpio": {"supply_max_v": 17.0}}}, env={}, search_paths=())
    # A smaller divider ratio cannot read the default range: 3.3 x 27.4 / 7.4 = 12.22 V.
    [smaller] = problems({"adc": True, "divider_r1_ohm": 20000.0})
    assert "winch.gpio.supply_max_v = 16.0 (default)" in smaller and "12.22 V" in smaller
    # Narrower than two ADC steps (2 x 16.41 / 1024 = 0.032 V): no reading fits in it.
    [narrow] = problems({"adc": True, "supply_min_v": 12.0, "supply_max_v": 12.02})
    assert "narrower than two steps of the ADC" in narrow and "0.032 V" in narrow


def test_an_overcurrent_limit_the_sensor_cannot_read_names_the_keys() -> None:
    # (3.3 x 0.998 - 2.5) / 0.185 = 4.29 A: a 5 A limit could never be seen.
    [over] = problems({"adc": True, "max_current_a": 5.0})
    assert over.startswith(
        "winch.gpio.max_current_a = 5.0 (from the command line), winch.gpio.adc_vref_v = 3.3 "
        "(default), winch.gpio.current_zero_v = 2.5 (default) and winch.gpio.current_v_per_a "
        "= 0.185 (default): impossible combination"
    )
    assert "4.29 A at the ADC's top" in over
    # The default is readable; without the ADC nothing reads the current: not refused.
    load_settings(None, {"winch": {"gpio": {"adc": True}}}, env={}, search_paths=())
    load_settings(None, {"winch": {"gpio": {"max_current_a": 5.0}}}, env={}, search_paths=())


def test_the_daemon_exits_2_on_a_supply_range_it_cannot_read(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "c.toml"
    config.write_text("[winch]\nbackend = 'gpio'\n[winch.gpio]\nadc = true\nsupply_max_v = 24.0\n")
    assert main(["--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert f"winch.gpio.supply_max_v = 24.0 (from {config})" in err
    assert "winch.gpio.divider_r2_ohm" in err


# ---------------------------------------------------------------- the driver, step by step


@contextlib.contextmanager
def sensing(
    faults: DrumFaults, now: list[float]
) -> Iterator[tuple[MotorSensing, list[tuple[str, dict[str, Any]]]]]:
    """MotorSensing on the mock MCP3008 of a drum that does not run, on fake time."""
    gpio = settings(adc=True)
    factory = SimulatedDrum.factory_for(gpio)
    drum = SimulatedDrum(factory, gpio, faults=faults)
    devices = open_devices(gpio, factory)
    events: list[tuple[str, dict[str, Any]]] = []
    try:
        yield (
            MotorSensing(
                gpio,
                devices,
                lambda kind, **detail: events.append((kind, detail)),
                monotonic=lambda: now[0],
            ),
            events,
        )
    finally:
        devices.close()
        drum.close()
        factory.reset()


def test_a_supply_still_out_of_range_is_summed_up_once_a_second() -> None:
    now = [100.0]
    with (
        sensing(DrumFaults(supply_v=6.0), now) as (sense, events),
        structlog.testing.capture_logs() as logs,
    ):
        for _ in range(5):  # five moves' zero checks within the same second
            sense.zero_check()
            now[0] += 0.1
        now[0] += 0.6  # a second after the fault was said
        sense.check_supply()
    assert [kind for kind, _ in events] == ["winch_sensor_fault"]
    [(_, event)] = events
    assert event["sensor"] == "supply" and event["supply_v"] == pytest.approx(6.0, abs=0.02)
    assert (event["supply_min_v"], event["supply_max_v"]) == (9.0, 16.0)
    assert event["fallback"] == "stall-by-pulses"
    assert [e["event"] for e in logs if e["log_level"] == "error"] == [FALLBACK]
    [summary] = [e for e in logs if e["log_level"] == "warning"]
    assert summary["event"] == "winch supply still cannot be true"
    assert (summary["readings"], summary["since_fault"]) == (5, 5)
    assert sense.current_a(motor_on=False) is None  # the ADC is not trusted for the current


def test_the_supply_is_read_once_every_so_many_readings_of_the_running_motor() -> None:
    now = [0.0]
    faults = DrumFaults()
    with sensing(faults, now) as (sense, events):
        sense.zero_check()
        faults.supply_v = 30.0  # reads full scale, 16.41 V
        for _ in range(SUPPLY_EVERY - 1):
            sense.current_a(motor_on=True)
        assert events == []
        assert sense.current_a(motor_on=True) is None  # the SUPPLY_EVERY-th: the supply read
        [(_, event)] = events
        assert event["sensor"] == "supply" and event["supply_v"] == pytest.approx(16.41, abs=0.02)
        assert "above supply_max_v 16 V" in (sense.fault or "")


def test_a_second_kind_of_fault_is_said_but_not_the_fallback_again() -> None:
    now = [0.0]
    faults = DrumFaults(current_adc=1.0)
    with sensing(faults, now) as (sense, events), structlog.testing.capture_logs() as logs:
        sense.zero_check()  # the current at its rail
        faults.supply_v = 6.0
        sense.zero_check()
        sense.zero_check()
    assert [d["sensor"] for _, d in events] == ["current", "supply"]
    assert "fallback" in events[0][1] and "fallback" not in events[1][1]
    assert [e["event"] for e in logs if e["log_level"] == "error"] == [
        FALLBACK,
        "winch sensor fault (overcurrent protection already by pulses)",
    ]
    assert (sense.fault or "").count(";") == 1  # both, in order


# ---------------------------------------------------------------- the GPIO winch on mock pins


@contextlib.asynccontextmanager
async def logged_rig(
    **kwargs: Any,
) -> AsyncIterator[tuple[GpioRig, list[MutableMapping[str, Any]]]]:
    with structlog.testing.capture_logs() as logs:
        async with gpio_rig(adc=True, **kwargs) as rig:
            yield rig, logs


async def test_a_noisy_current_sensor_is_one_fault_and_the_move_ends_by_pulses() -> None:
    async with logged_rig(faults=DrumFaults(current_noise_seed=1)) as (rig, logs):
        rig.winch.move_to(1.0)  # the zero check is clean: the noise comes with the motor
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is None and abs(status.depth_m - 1.0) <= MPP / 2
        rig.winch.move_to(0.0)
        await rig.settle()
        home = rig.winch.status()
        assert home.at_home and home.fault is None
    [event] = sensor_faults(rig)
    assert event["sensor"] == "current" and "jumped" in event["fault"]
    assert event["fallback"] == "stall-by-pulses"
    assert [e["event"] for e in logs].count(FALLBACK) == 1
    assert "jumped" in (rig.winch.sensor_fault or "")
    # The status document and `cc-daemon status` say it too, the winch still at home.
    assert home.sensor_fault == rig.winch.sensor_fault
    doc = {"winch": {"backend": "gpio", "at_home": True, "sensor_fault": home.sensor_fault}}
    winch_row = dict(status_lines(doc))["winch"]
    assert winch_row.startswith("gpio: stopped, home, SENSOR FAULT (overcurrent by pulses only)")


async def test_a_jam_read_by_a_sane_sensor_is_still_an_overcurrent_stall() -> None:
    # 1.05 A running (0.945 A at 0.9 duty), 4.2 A jammed: past max_current_a 4.0 and
    # within the 4.32 A the ADC reads. The pulses' stall waits longer than the current's.
    async with logged_rig(faults=DrumFaults(jam_at_m=0.8), stall_timeout_s=2.0) as (rig, logs):
        rig.drum.running_current_a = 1.05
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("stall: motor current")
        assert rig.drum.motor() == (0, 0.0)
    assert sensor_faults(rig) == [] and rig.winch.sensor_fault is None
    [fault] = [d for k, d in rig.events if k == "winch_fault"]
    assert fault["peak_current_a"] == pytest.approx(4.2, abs=0.05)
    assert FALLBACK not in [e["event"] for e in logs]


async def test_a_jam_past_the_sensors_range_is_an_overcurrent_stall_not_a_sensor_fault() -> None:
    # The mock drum's own jam: 4 x 1.2 A = 4.8 A, more than the 4.32 A the ADC reads.
    # The reading sits at the top rail with the motor running: the jam, stopped by the
    # current in overcurrent_s, the sensor still trusted (it read 0 A at rest).
    async with logged_rig(faults=DrumFaults(jam_at_m=0.8), stall_timeout_s=2.0) as (rig, logs):
        rig.winch.move_to(3.0)
        await rig.settle()
        status = rig.winch.status()
        assert status.fault is not None and status.fault.startswith("stall: motor current")
        assert rig.drum.motor() == (0, 0.0)
        rig.winch.move_to(0.0)  # the zero check at rest: the sensor reads 0 A, still sane
        await rig.settle()
        assert rig.winch.status().at_home
    assert sensor_faults(rig) == [] and rig.winch.sensor_fault is None
    assert FALLBACK not in [e["event"] for e in logs]


@pytest.mark.parametrize(("volts", "reads"), [(6.0, 6.0), (30.0, 16.41)], ids=["6V", "30V"])
async def test_a_supply_out_of_range_is_one_fault_and_casts_go_on(
    volts: float, reads: float
) -> None:
    async with logged_rig(faults=DrumFaults(supply_v=volts)) as (rig, logs):
        for depth in (1.0, 0.0):  # two zero checks, one fault
            rig.winch.move_to(depth)
            await rig.settle()
            assert rig.winch.status().fault is None
        line = _line(rig.winch, rig.winch._cfg)
    [event] = sensor_faults(rig)
    assert event["sensor"] == "supply" and event["supply_v"] == pytest.approx(reads, abs=0.02)
    assert [e["event"] for e in logs].count(FALLBACK) == 1
    # The `cc-daemon winch` readout says both: the reading now, and the fault.
    assert f"supply {reads:5.2f} V  (cannot be true: outside 9 to 16 V)" in line
    assert "SENSOR FAULT (overcurrent by pulses only): supply voltage reads" in line


async def test_with_the_supply_untrusted_overcurrent_is_left_to_the_pulses() -> None:
    # The current shares the ADC with a supply that cannot be true: 4.2 A is not
    # believed, and the pulses (turning: no stall) let the move finish.
    async with gpio_rig(adc=True, faults=DrumFaults(supply_v=6.0, overcurrent_a=4.2)) as rig:
        rig.winch.move_to(1.5)
        await rig.settle()
        assert rig.winch.status().fault is None
        assert [e["sensor"] for e in sensor_faults(rig)] == ["supply"]


async def test_the_supply_failing_mid_move_is_found_while_the_motor_runs() -> None:
    async with gpio_rig(adc=True) as rig:
        rig.winch.move_to(3.0)  # 3 s of line at the kit's 1 m/s: 2 supply readings at least
        await wait_for(lambda: rig.drum.line_m > 0.3)
        rig.drum.faults.supply_v = 6.0
        await rig.settle()
        # No zero check since the supply failed: only a reading of the running motor
        # can have found it; and the move went on to its target.
        [event] = sensor_faults(rig)
        assert event["sensor"] == "supply" and event["supply_v"] == pytest.approx(6.0, abs=0.02)
        assert rig.winch.status().fault is None
        assert abs(rig.winch.status().depth_m - 3.0) <= MPP / 2


async def test_an_adc_that_stops_answering_mid_move_is_a_sensor_fault_not_a_stop() -> None:
    async with gpio_rig(adc=True) as rig:
        rig.winch.move_to(2.0)
        await wait_for(lambda: rig.drum.line_m > 0.3)
        adc = rig.winch._dev.current
        assert adc is not None
        adc.close()  # the next reading raises
        await rig.settle()
        assert rig.winch.status().fault is None
        [event] = sensor_faults(rig)
        assert event["sensor"] == "current" and "could not be read" in event["fault"]


def test_the_zero_is_not_judged_while_a_stopped_windings_current_dies_away() -> None:
    # A move replacing a running one starts straight after the stop: 2 A then may be
    # the winding's current, not the sensor. Once the motor has been off long enough,
    # the same reading is the sensor's fault.
    with sensing(DrumFaults(current_adc=0.87), [100.0]) as (sense, events):
        sense.zero_check(ZERO_SETTLE_S / 4)
        assert sense.fault is None and events == []
        sense.zero_check(ZERO_SETTLE_S)
        assert sense.fault is not None and "with the motor off" in sense.fault


async def test_the_h_bridge_remembers_when_a_running_motor_stopped() -> None:
    async with gpio_rig() as rig:
        bridge = rig.winch._bridge
        before = bridge.stopped_at
        bridge.stop()  # already stopped: not a stop of a running motor
        assert bridge.stopped_at == before
        rig.winch.move_to(0.5)
        stopping = time.monotonic()
        rig.winch.stop()
        assert stopping <= bridge.stopped_at <= time.monotonic()
