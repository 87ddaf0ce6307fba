"""The winch's keys: `[winch]`, the simulated winch (`[winch.sim]`) and the GPIO winch
(`[winch.gpio]`), with the combinations of them that could never work (a debounce
that loses pulses, a stall rule that fires at the winch's own slowest speed, an
ADC that cannot read the zero or the overcurrent). Reads nothing but its arguments.
"""

from typing import Annotated, Literal, Self

from pydantic import BaseModel, BeforeValidator, Field, model_validator

from cc_daemon.config.rules import _SECTION, _empty_is_none, _impossible, _NonNegative, _Positive
from cc_daemon.core.winch.drum import CurrentSensor, Drum, VoltageDivider
from cc_daemon.core.winch.encoder import max_pulse_rate
from cc_daemon.core.winch.sensors import RAIL_MARGIN, TURNING_MIN_A
from cc_daemon.core.winch.status import APPROACH_FRACTION

STALL_MARGIN = 1.5  # the stall rule's time over the pulse period at the slowest motion


class WinchSimSettings(BaseModel):
    """[winch.sim]: the simulated winch's physics and its fault injection (for tests)."""

    model_config = _SECTION

    speed_m_s: _Positive = 0.25
    stall_at_m: Annotated[_Positive | None, BeforeValidator(_empty_is_none)] = None
    fail_home: bool = False
    # The mock drum's sensor fault (--winch gpio-mock --winch-fault NAME): a switch
    # stuck closed, a snag at 1 m, the current sensor's ADC at full scale, a pulse
    # storm from 1 m down, the pulse pin dead from the first haul in below 1 m.
    drum_fault: Literal[
        "none", "switch-stuck", "snag", "adc-garbage", "pulse-storm", "encoder-dead"
    ] = "none"
    # Outside --simulate a simulated winch would answer a real autopilot for a probe
    # that never moves: it runs only when this says so in so many words.
    allow_outside_simulation: bool = False


_Bcm = Annotated[int, Field(ge=0, le=27)]
_Duty = Annotated[float, Field(gt=0, le=1)]
_Pull = Literal["none", "up", "down"]
_Level = Literal["high", "low"]


class WinchGpioSettings(BaseModel):
    """[winch.gpio]: the real winch on the Pi's GPIO (BCM numbers); defaults from the
    group's previous controller where it had one (docs/gpio-winch.md says which)."""

    model_config = _SECTION

    pin_factory: Literal["native", "mock"] = "native"
    payout_pin: _Bcm = 5
    haulin_pin: _Bcm = 0
    enable_pin: _Bcm = 13
    pwm_frequency_hz: Annotated[float, Field(gt=0, le=100_000)] = 1000.0
    payout_duty: _Duty = 0.9
    haulin_duty: _Duty = 0.9
    ramp_s: _NonNegative = 0.2
    approach_m: _NonNegative = 0.1
    switch_pin: _Bcm = 17
    switch_pull: _Pull = "none"
    switch_active: _Level = "high"
    switch_debounce_s: Annotated[float, Field(ge=0, le=1)] = 0.002
    # Home needs the switch closed this long as well as the count near zero.
    switch_settle_s: Annotated[float, Field(ge=0.01, le=2)] = 0.2
    counter: Literal["pulse", "quadrature"] = "pulse"
    pulse_pin: _Bcm = 27
    encoder_b_pin: _Bcm = 22
    pulse_pull: _Pull = "none"
    pulse_debounce_s: Annotated[float, Field(ge=0, le=1)] = 0.002
    pulses_per_rev: Annotated[int, Field(ge=1)] = 2
    drum_diameter_m: _Positive = 0.09
    line_speed_m_s: _Positive = 0.25
    # Safety times have physical upper bounds (docs/gpio-winch.md "Bounds").
    stall_timeout_s: Annotated[float, Field(gt=0, le=10)] = 2.0
    home_margin_s: Annotated[float, Field(ge=0, le=120)] = 10.0
    # A count 5 m off at home is no count (and its coasting allowance would let a
    # pulse storm of ~35 pulses pass as a drum).
    count_tolerance_m: Annotated[float, Field(gt=0, le=5)] = 0.5
    home_at_start: bool = True
    # At least four of the winch's 50 ms feeding ticks: any less trips on every move.
    loop_watchdog_s: Annotated[float, Field(ge=0.2, le=5)] = 1.0
    adc: bool = False
    adc_spi_device: Annotated[int, Field(ge=0, le=1)] = 0
    voltage_channel: Annotated[int, Field(ge=0, le=7)] = 0
    current_channel: Annotated[int, Field(ge=0, le=7)] = 1
    adc_vref_v: _Positive = 3.3
    current_zero_v: _NonNegative = 2.5
    current_v_per_a: _Positive = 0.185
    divider_r1_ohm: _Positive = 29400.0
    divider_r2_ohm: _Positive = 7400.0
    max_current_a: _Positive = 4.0
    overcurrent_s: Annotated[float, Field(gt=0, le=5)] = 0.5
    # The supply's possible range: a reading outside it is the supply or the ADC (a
    # sensor fault). A 12 V lead-acid system: flat at 10.5 V at rest and sagging
    # under the motor, so 9 V; 16 V is above any charger's equalisation (15.5 V).
    # At most 60 V: a safety-extra-low-voltage boat, past every H-bridge here.
    supply_min_v: Annotated[float, Field(ge=0, le=60)] = 9.0
    supply_max_v: Annotated[float, Field(gt=0, le=60)] = 16.0

    def pins(self) -> dict[str, int]:
        """Every GPIO this configuration claims, by key (SPI0 too when the ADC is on)."""
        used = {
            "payout_pin": self.payout_pin,
            "haulin_pin": self.haulin_pin,
            "enable_pin": self.enable_pin,
            "switch_pin": self.switch_pin,
            "pulse_pin": self.pulse_pin,
        }
        if self.counter == "quadrature":
            used["encoder_b_pin"] = self.encoder_b_pin
        return used

    @model_validator(mode="after")
    def _check(self) -> Self:
        # A pull resistor fixes which level is "open": a switch can only pull the other way.
        if (self.switch_pull, self.switch_active) in (("up", "high"), ("down", "low")):
            raise _impossible(
                '{0} = "'
                + self.switch_pull
                + '" needs {1} = "'
                + ("low" if self.switch_pull == "up" else "high")
                + '" (the pull holds the open switch at the other level)',
                "switch_pull",
                "switch_active",
            )
        seen: dict[int, str] = {}
        for key, pin in self.pins().items():
            if pin in seen:
                raise _impossible(
                    "{0} and {1} must be different pins (one GPIO cannot do both)", seen[pin], key
                )
            seen[pin] = key
        if self.adc:
            # SPI0: MOSI 10, MISO 9, SCLK 11, CE0 8 / CE1 7.
            spi = {10: "MOSI", 9: "MISO", 11: "SCLK", 8 - self.adc_spi_device: "CE"}
            for pin, key in seen.items():
                if pin in spi:
                    raise _impossible(
                        "{0} must not be an SPI0 pin (" + spi[pin] + ") when {1} is true",
                        key,
                        "adc",
                    )
            if self.voltage_channel == self.current_channel:
                raise _impossible(
                    "{0} and {1} must be different ADC channels",
                    "voltage_channel",
                    "current_channel",
                )
            if self.current_zero_v >= self.adc_vref_v:
                raise _impossible(
                    "{0} must be below {1} (the ADC could not read the zero)",
                    "current_zero_v",
                    "adc_vref_v",
                )
            if self.current_zero_v <= self.adc_vref_v * RAIL_MARGIN:
                raise _impossible(
                    "{0} must be above the ADC's bottom rail, {1} x "
                    + f"{RAIL_MARGIN:g} (0 A would read at the rail: every zero check a fault)",
                    "current_zero_v",
                    "adc_vref_v",
                )
        if self.supply_min_v >= self.supply_max_v:
            raise _impossible(
                "{0} must be below {1} (the supply's range would be empty)",
                "supply_min_v",
                "supply_max_v",
            )
        self._check_debounce()
        self._check_stall_timeout()
        if self.adc:
            self._check_supply_range()
            self._check_current_range()
        return self

    def _check_debounce(self) -> None:
        """A debounce as long as half the pulse period at full speed loses pulses."""
        metres_per_pulse = Drum(self.pulses_per_rev, self.drum_diameter_m).metres_per_pulse
        lowest = min(self.payout_duty, self.haulin_duty)
        period_s = 1 / max_pulse_rate(self.line_speed_m_s, lowest, metres_per_pulse)
        if self.pulse_debounce_s >= period_s / 2:
            raise _impossible(
                "{0} must be under half the pulse period at full speed, "
                + f"{period_s / 2:.4g} s from {{1}}, {{2}} and {{3}} (longer loses pulses)",
                "pulse_debounce_s",
                "line_speed_m_s",
                "drum_diameter_m",
                "pulses_per_rev",
            )

    def _check_stall_timeout(self) -> None:
        """The winch's slowest motion (the approach duty: the end of every move, a blind
        cast, a descent slowed to what the sonde resolves) must give a pulse well within
        the stall rule's time, or every such motion is a stall: 1.5 times the period."""
        metres_per_pulse = Drum(self.pulses_per_rev, self.drum_diameter_m).metres_per_pulse
        # line_speed_m_s is at payout_duty; a duty d turns the drum d / payout_duty as fast.
        slowest_duty = min(self.payout_duty, self.haulin_duty) * APPROACH_FRACTION
        slowest_m_s = self.line_speed_m_s * slowest_duty / self.payout_duty
        period_s = metres_per_pulse / slowest_m_s
        if self.stall_timeout_s < STALL_MARGIN * period_s:
            raise _impossible(
                "{0} must be at least "
                + f"{STALL_MARGIN * period_s:.3g} s: at the approach speed ({APPROACH_FRACTION:g}"
                + " of the duty) a pulse comes every "
                + f"{period_s:.3g} s from {{1}}, {{2}} and {{3}}, and each slow motion would stall",
                "stall_timeout_s",
                "line_speed_m_s",
                "drum_diameter_m",
                "pulses_per_rev",
            )

    def _check_current_range(self) -> None:
        """An overcurrent the sensor cannot read could never be seen: max_current_a must
        be below the most the sensor reads before the ADC's top rail."""
        sensor = CurrentSensor(self.adc_vref_v, self.current_zero_v, self.current_v_per_a)
        top_a = sensor.amps(1 - RAIL_MARGIN)
        if self.max_current_a <= TURNING_MIN_A:
            raise _impossible(
                "{0} must be above "
                + f"{TURNING_MIN_A:g} A, the least a turning motor draws (a silent drum "
                + "could never be told from a jam)",
                "max_current_a",
            )
        if self.max_current_a >= top_a:
            raise _impossible(
                "{0} must be below the most the current sensor reads, ({1} - {2}) / {3} = "
                + f"{top_a:.2f} A at the ADC's top (a higher current reads there, "
                + "never above {0})",
                "max_current_a",
                "adc_vref_v",
                "current_zero_v",
                "current_v_per_a",
            )

    def _check_supply_range(self) -> None:
        """The supply's range must be one the divider can tell from outside it."""
        divider = VoltageDivider(self.adc_vref_v, self.divider_r1_ohm, self.divider_r2_ohm)
        full_scale = divider.volts(1.0)
        if self.supply_max_v >= full_scale:
            raise _impossible(
                "{0} must be below the most the divider can read, {1} x ({2} + {3}) / {3} = "
                + f"{full_scale:.2f} V (a supply above it reads full scale, never above {{0}})",
                "supply_max_v",
                "adc_vref_v",
                "divider_r1_ohm",
                "divider_r2_ohm",
            )
        if self.supply_min_v <= full_scale * RAIL_MARGIN:
            raise _impossible(
                "{0} must be above the ADC's bottom rail through the divider, "
                + f"{full_scale * RAIL_MARGIN:.3f} V (a dead channel reading 0 V would pass)",
                "supply_min_v",
            )
        step = 2 * full_scale / 1024  # two steps of the 10-bit MCP3008
        if self.supply_max_v - self.supply_min_v < step:
            raise _impossible(
                "{0} to {1} is narrower than two steps of the ADC through the divider "
                + f"({step:.3f} V): no reading could be trusted inside it",
                "supply_min_v",
                "supply_max_v",
            )


class WinchSettings(BaseModel):
    """[winch]: which backend drives the probe and how much line it has."""

    model_config = _SECTION

    backend: Literal["sim", "gpio"] = "sim"
    max_line_m: _Positive = 20.0
    sim: WinchSimSettings = WinchSimSettings()
    gpio: WinchGpioSettings = WinchGpioSettings()

    @model_validator(mode="after")
    def _check(self) -> Self:
        if self.sim.stall_at_m is not None and self.sim.stall_at_m >= self.max_line_m:
            raise _impossible(
                "{0} must be less than {1} (the line ends before the stall)",
                "sim.stall_at_m",
                "max_line_m",
            )
        return self
