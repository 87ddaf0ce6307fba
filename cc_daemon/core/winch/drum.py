"""The arithmetic of a winch drum and its sensors: pulses to line, ADC to amps and volts.

Pure: numbers in, numbers out. It owns how a pulse count becomes metres of line
(revolutions x circumference, and that is the probe's depth) and how the
MCP3008's readings become motor current and supply voltage. It never touches a
pin, a thread or a clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Drum:
    """A drum of `diameter_m` whose sensor gives `pulses_per_rev` counts a turn."""

    pulses_per_rev: int
    diameter_m: float

    def __post_init__(self) -> None:
        if self.pulses_per_rev < 1:
            raise ValueError("pulses_per_rev must be >= 1")
        if not self.diameter_m > 0:
            raise ValueError("diameter_m must be > 0")

    @property
    def metres_per_pulse(self) -> float:
        return math.pi * self.diameter_m / self.pulses_per_rev

    def line_m(self, count: int) -> float:
        """Line out for a signed pulse count (negative: wound past the zero)."""
        return count * self.metres_per_pulse

    def count_at(self, line_m: float) -> int:
        """The count nearest `line_m`: stopping there leaves the line within half a pulse."""
        return round(line_m / self.metres_per_pulse)


@dataclass(frozen=True, slots=True)
class CurrentSensor:
    """A Hall current sensor (ACS712: `volts_per_amp` around `zero_v`) on an ADC."""

    vref_v: float
    zero_v: float
    volts_per_amp: float

    def amps(self, fraction: float) -> float:
        """Current for an ADC reading given as a fraction of full scale (0..1)."""
        return (fraction * self.vref_v - self.zero_v) / self.volts_per_amp


@dataclass(frozen=True, slots=True)
class VoltageDivider:
    """The supply seen through r1 (to the supply) over r2 (to ground) on an ADC."""

    vref_v: float
    r1_ohm: float
    r2_ohm: float

    def volts(self, fraction: float) -> float:
        return fraction * self.vref_v * (self.r1_ohm + self.r2_ohm) / self.r2_ohm

    def fraction(self, volts: float) -> float:
        """The ADC fraction that reads `volts` (for a simulated supply)."""
        return volts * self.r2_ohm / (self.r1_ohm + self.r2_ohm) / self.vref_v


def current_fraction(sensor: CurrentSensor, amps: float) -> float:
    """The ADC fraction that reads `amps` (for a simulated motor), clipped to 0..1."""
    return min(max((sensor.zero_v + amps * sensor.volts_per_amp) / sensor.vref_v, 0.0), 1.0)
