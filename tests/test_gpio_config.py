"""[winch.gpio]: what a bad value says (exit 2, naming the key), and the pure arithmetic
and safety rules of the GPIO winch on fake time."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.cli.app import main
from cc_daemon.config import load_settings
from cc_daemon.core.errors import ConfigError
from cc_daemon.core.winch.drum import CurrentSensor, Drum, VoltageDivider, current_fraction
from cc_daemon.core.winch.safety import Limits, MotionGuard

PREFIX = "cc-daemon: bad configuration: "


def problems(gpio: dict[str, object]) -> list[str]:
    with pytest.raises(ConfigError) as caught:
        load_settings(None, {"winch": {"gpio": gpio}}, env={}, search_paths=())
    return [line.removeprefix(PREFIX) for line in str(caught.value).splitlines()]


@pytest.mark.parametrize(
    ("gpio", "expected"),
    [
        (
            {"payout_pin": 28},
            "winch.gpio.payout_pin = 28 (from the command line): must be at most 27",
        ),
        (
            {"enable_pin": -1},
            "winch.gpio.enable_pin = -1 (from the command line): must be at least 0",
        ),
        (
            {"payout_duty": 0},
            "winch.gpio.payout_duty = 0 (from the command line): must be greater than 0",
        ),
        (
            {"haulin_duty": 1.5},
            "winch.gpio.haulin_duty = 1.5 (from the command line): must be at most 1",
        ),
        (
            {"drum_diameter_m": 0},
            "winch.gpio.drum_diameter_m = 0 (from the command line): must be greater than 0",
        ),
        (
            {"pulses_per_rev": 0},
            "winch.gpio.pulses_per_rev = 0 (from the command line): must be at least 1",
        ),
        (
            {"counter": "hall"},
            'winch.gpio.counter = "hall" (from the command line): '
            'must be one of "pulse" or "quadrature"',
        ),
    ],
)
def test_a_bad_value_names_its_key(gpio: dict[str, object], expected: str) -> None:
    assert problems(gpio) == [expected]


def test_a_stall_rule_every_slow_motion_would_break_is_refused() -> None:
    # One pulse a turn of the 0.09 m drum at the approach speed (half of 0.25 m/s):
    # a pulse every 2.26 s, and the default 2 s stall rule would stop each approach,
    # blind cast and descent slowed for the sonde (found by a review of issue 28).
    [line] = problems({"pulses_per_rev": 1})
    assert line.startswith("winch.gpio.stall_timeout_s = 2.0 (default), ")
    assert "winch.gpio.pulses_per_rev = 1 (from the command line): " in line
    assert "winch.gpio.stall_timeout_s must be at least 3.39 s" in line
    assert "a pulse comes every 2.26 s" in line
    settings = load_settings(
        None,
        {"winch": {"gpio": {"pulses_per_rev": 1, "stall_timeout_s": 3.5}}},
        env={},
        search_paths=(),
    )
    assert settings.winch.gpio.stall_timeout_s == 3.5


def test_pins_must_be_distinct_and_fit_the_circuit() -> None:
    assert problems({"haulin_pin": 27}) == [
        "winch.gpio.haulin_pin = 27 (from the command line) and winch.gpio.pulse_pin = 27 "
        "(default): impossible combination: winch.gpio.haulin_pin and winch.gpio.pulse_pin "
        "must be different pins (one GPIO cannot do both)"
    ]
    # Channel B only counts with a quadrature encoder.
    load_settings(None, {"winch": {"gpio": {"encoder_b_pin": 5}}}, env={}, search_paths=())
    assert "must be different pins" in problems({"counter": "quadrature", "encoder_b_pin": 5})[0]
    assert "must not be an SPI0 pin (SCLK)" in problems({"adc": True, "switch_pin": 11})[0]
    assert "different ADC channels" in problems({"adc": True, "current_channel": 0})[0]
    assert problems({"switch_pull": "down", "switch_active": "low"})[0].endswith(
        'winch.gpio.switch_pull = "down" needs winch.gpio.switch_active = "high" '
        "(the pull holds the open switch at the other level)"
    )


def test_the_daemon_exits_2_on_a_bad_gpio_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "c.toml"
    config.write_text("[winch]\nbackend = 'gpio'\n[winch.gpio]\nswitch_pin = 40\n")
    assert main(["--config", str(config)]) == 2
    assert f"winch.gpio.switch_pin = 40 (from {config}): must be at most 27" in (
        capsys.readouterr().err
    )
    assert main(["winch", "--config", str(config), "status"]) == 2


def test_line_out_is_turns_times_circumference() -> None:
    drum = Drum(pulses_per_rev=2, diameter_m=0.09)  # the old controller's drum
    assert drum.metres_per_pulse == pytest.approx(math.pi * 0.09 / 2)
    assert drum.line_m(20) == pytest.approx(10 * math.pi * 0.09)
    assert drum.count_at(2.0) == 14  # 14 x 0.1414 = 1.979 m: within half a pulse
    assert abs(drum.line_m(drum.count_at(2.0)) - 2.0) <= drum.metres_per_pulse / 2
    with pytest.raises(ValueError, match="pulses_per_rev"):
        Drum(0, 0.09)


def test_the_adc_readings_become_amps_and_volts() -> None:
    acs712 = CurrentSensor(vref_v=3.3, zero_v=2.5, volts_per_amp=0.185)
    assert acs712.amps(2.5 / 3.3) == pytest.approx(0.0)
    assert acs712.amps(1.0) == pytest.approx((3.3 - 2.5) / 0.185)  # the most it can read
    assert acs712.amps(current_fraction(acs712, 2.0)) == pytest.approx(2.0)
    divider = VoltageDivider(vref_v=3.3, r1_ohm=29_400, r2_ohm=7_400)
    assert divider.volts(divider.fraction(12.0)) == pytest.approx(12.0)
    assert divider.volts(1.0) == pytest.approx(3.3 * 36.8 / 7.4)


MOTION: dict[str, Any] = {"direction": 1, "full_speed_m_s": 0.5}


def test_stall_overcurrent_and_home_deadline_on_fake_time() -> None:
    limits = Limits(stall_timeout_s=2.0, max_current_a=4.0, overcurrent_s=0.5)
    guard = MotionGuard(limits, started_at=100.0, home_deadline=None, **MOTION)
    assert guard.check(101.9, None, 0.5, duty=0.9) is None
    guard.pulse(101.9)
    assert guard.check(103.8, None, 0.6, duty=0.9) is None
    fault = guard.check(104.0, None, 0.6, duty=0.9)
    assert fault is not None and fault.startswith("stall: no drum pulse for 2.1 s")

    guard = MotionGuard(limits, started_at=0.0, home_deadline=None, **MOTION)
    for t in (0.1, 0.3, 0.5):
        guard.pulse(t)
    assert guard.check(0.2, 4.5, 1.0, duty=0.9) is None  # over, but not for long yet
    assert guard.check(0.4, 3.0, 1.0, duty=0.9) is None  # back under: the clock restarts
    assert guard.check(0.5, 4.5, 1.0, duty=0.9) is None
    guard.pulse(1.0)
    over = guard.check(1.05, 4.6, 1.0, duty=0.9)
    assert over is not None and "motor current 4.60 A" in over
    assert guard.peak_current_a == pytest.approx(4.6)

    guard = MotionGuard(limits, started_at=0.0, home_deadline=3.0, **MOTION)
    guard.pulse(2.9)
    assert guard.check(2.95, None, 0.4, duty=0.9) is None
    late = guard.check(3.1, None, 0.4, duty=0.9)
    assert late is not None and late.startswith("home not reached")
