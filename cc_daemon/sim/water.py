"""A water-column model of a small reservoir in summer, for the simulated sonde.

Pure: `WaterColumn.truth(depth_m, t)` gives each quantity at a depth and time
(a thermocline, oxygen falling below it, a chlorophyll maximum under the
surface, phycocyanin near the top, a slow pH drift); `SondeModel` adds what a
real sonde adds on top (first-order sensor lag, noise, the pressure depth of a
probe on a slanted line, a bottom it cannot go through). Randomness comes from
the `random.Random` it is given, so a seed makes a run repeatable. It never
reads a clock: the caller passes `t`.

A lagging sensor sees the water all the time, not only when it is read: between
two readings `SondeModel` integrates each sensor's first-order response along the
probe's path (in steps of at most `_STEP_S`), so its lag is the sensor's time
constant whatever the sampling period. (Updating once per reading with the water
of that instant, as it once did, made a 2 s thermistor lag 1.54 s when read once
a second and 1.95 s when read ten times a second.)
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

__all__ = ["LAG_S", "SondeModel", "WaterColumn"]


def _oxygen_solubility_mg_l(temp_c: float) -> float:
    # Fresh water at sea-level pressure, a cubic fit good to ~0.1 mg/L for 0-30 degC.
    t = temp_c
    return 14.62 - 0.3898 * t + 0.006969 * t**2 - 5.897e-5 * t**3


@dataclass(frozen=True, slots=True)
class WaterColumn:
    surface_temp_c: float = 24.0
    bottom_temp_c: float = 12.0
    thermocline_m: float = 4.0
    thermocline_width_m: float = 0.7
    chlorophyll_max_m: float = 3.0
    bottom_m: float = 12.0
    # Oxygen saturation above and below the thermocline, percent.
    epilimnion_do_saturation_pct: float = 105.0
    hypolimnion_do_saturation_pct: float = 25.0

    def truth(self, depth_m: float, t: float) -> dict[str, float]:
        z = max(depth_m, 0.0)
        mixed = 1.0 / (1.0 + math.exp((z - self.thermocline_m) / self.thermocline_width_m))
        temp = self.bottom_temp_c + (self.surface_temp_c - self.bottom_temp_c) * mixed
        low, high = self.hypolimnion_do_saturation_pct, self.epilimnion_do_saturation_pct
        saturation = low + (high - low) * mixed + 6.0 * math.exp(-(((z - 2.5) / 1.0) ** 2))
        return {
            "depth": z,
            "temperature": temp,
            "ph": 7.3 + 1.2 * mixed + 0.03 * math.sin(t / 900.0),
            "do_saturation": saturation,
            "do_concentration": saturation / 100.0 * _oxygen_solubility_mg_l(temp),
            "blue": 0.4 + 1.8 * math.exp(-(((z - 1.0) / 1.2) ** 2)),
            "chlorophyll": 1.5 + 9.0 * math.exp(-(((z - self.chlorophyll_max_m) / 0.8) ** 2)),
        }


# Time constants of the sensors, seconds (a DO membrane is slow, a thermistor quick).
LAG_S = {"temperature": 2.0, "do_saturation": 8.0, "do_concentration": 8.0, "ph": 4.0}
# The response is integrated in steps this long at most, and in at most this many.
_STEP_S = 0.1
_MAX_STEPS = 100
_NOISE = {
    "depth": 0.01,
    "temperature": 0.01,
    "ph": 0.005,
    "do_saturation": 0.3,
    "do_concentration": 0.03,
    "blue": 0.05,
    "chlorophyll": 0.15,
}


@dataclass(slots=True)
class SondeModel:
    """What the sonde reads when its line is `line_out_m` out at time `t`."""

    water: WaterColumn = field(default_factory=WaterColumn)
    slant_deg: float = 8.0
    rng: random.Random = field(default_factory=lambda: random.Random(0))
    _state: dict[str, float] = field(default_factory=dict)
    _t: float | None = None
    _depth: float = 0.0

    def depth_for(self, line_out_m: float) -> float:
        """The probe's true depth: the line is slanted by drift, and the bottom stops it."""
        return min(
            max(line_out_m, 0.0) * math.cos(math.radians(self.slant_deg)), self.water.bottom_m
        )

    def read(self, line_out_m: float, t: float) -> dict[str, float]:
        depth = self.depth_for(line_out_m)
        truth = self.water.truth(depth, t)
        if self._t is None:
            self._state = {name: truth[name] for name in LAG_S}
        else:
            self._respond(depth, t)
        self._t, self._depth = t, depth
        out: dict[str, float] = {}
        for name, true_value in truth.items():
            sensed = self._state.get(name, true_value)
            out[name] = sensed + self.rng.gauss(0.0, _NOISE.get(name, 0.0))
        return out

    def _respond(self, depth: float, t: float) -> None:
        """Each lagging sensor's response from the last reading to `t`, the probe moving
        in a straight line from the last reading's depth to `depth` meanwhile (exact
        within a leg of the winch, which runs at a constant speed)."""
        assert self._t is not None
        dt = max(t - self._t, 0.0)
        steps = min(max(math.ceil(dt / _STEP_S), 1), _MAX_STEPS)
        step = dt / steps
        for k in range(steps):
            f = (k + 0.5) / steps
            water = self.water.truth(self._depth + (depth - self._depth) * f, self._t + dt * f)
            for name, lag in LAG_S.items():
                self._state[name] += (water[name] - self._state[name]) * (1 - math.exp(-step / lag))
