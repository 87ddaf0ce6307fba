"""The simulated sonde's sensors lag as first-order sensors do: by their time constant,
whatever the sampling period; and the water column's parameters shape the truth."""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

import pytest

from cc_daemon.sim.water import LAG_S, SondeModel, WaterColumn

SPEED_M_S = 0.25  # the winch at real pace
GRADIENT_C_PER_M = 10.0  # steep, so that a tenth of a second of lag is a quarter degree


@dataclass(frozen=True, slots=True)
class Ramp(WaterColumn):
    """Temperature falling linearly with depth: a first-order sensor descending at a
    constant speed then reads the water of exactly its time constant ago."""

    def truth(self, depth_m: float, t: float) -> dict[str, float]:
        values = WaterColumn.truth(self, depth_m, t)
        values["temperature"] = 30.0 - GRADIENT_C_PER_M * max(depth_m, 0.0)
        return values


def descend(period_s: float, until_s: float) -> tuple[float, float]:
    """Read the sonde every `period_s` while it descends at SPEED_M_S from t = 0; the
    last reading's temperature and the true temperature then."""
    model = SondeModel(Ramp(bottom_m=100.0), slant_deg=0.0, rng=random.Random(1))
    steps = round(until_s / period_s)
    reading = {}
    for k in range(steps + 1):
        t = k * period_s
        reading = model.read(SPEED_M_S * t, t)
    true_now = 30.0 - GRADIENT_C_PER_M * SPEED_M_S * until_s
    return reading["temperature"], true_now


@pytest.mark.parametrize("period_s", [1.0, 0.5, 0.2, 2.0])
def test_a_descending_sensor_lags_by_its_time_constant_at_any_sampling_period(
    period_s: float,
) -> None:
    tau = LAG_S["temperature"]
    sensed, true_now = descend(period_s, until_s=40.0)  # 20 time constants: steady state
    # The water of tau seconds ago, to a fiftieth of the lag (the noise is 0.01 degC).
    rate = GRADIENT_C_PER_M * SPEED_M_S
    assert sensed - true_now == pytest.approx(rate * tau, rel=0.02)


def test_the_response_to_a_step_is_exponential() -> None:
    """The probe stands in 20 degC water, is dropped at once into 10 degC water, and
    read every second: 1 - exp(-t / tau) of the step after t seconds."""

    @dataclass(frozen=True, slots=True)
    class Step(WaterColumn):
        def truth(self, depth_m: float, t: float) -> dict[str, float]:
            values = WaterColumn.truth(self, depth_m, t)
            values["temperature"] = 20.0 if depth_m < 1.0 else 10.0
            return values

    model = SondeModel(Step(), slant_deg=0.0, rng=random.Random(2))
    model.read(0.0, 0.0)
    model.read(0.0, 10.0)
    model.read(5.0, 10.001)  # dropped in a millisecond
    tau = LAG_S["temperature"]
    for t in (1.0, 2.0, 4.0):
        sensed = model.read(5.0, 10.001 + t)["temperature"]
        assert sensed == pytest.approx(10.0 + 10.0 * math.exp(-t / tau), abs=0.05)


def test_water_column_parameters_shape_the_truth() -> None:
    default = WaterColumn()
    # The defaults are the column the simulator has always had.
    assert default.truth(0.0, 0.0)["do_saturation"] == pytest.approx(
        25.0 + 80.0 / (1 + math.exp(-4.0 / 0.7)) + 6.0 * math.exp(-6.25)
    )
    hypoxic = WaterColumn(hypolimnion_do_saturation_pct=5.0)
    assert hypoxic.truth(10.0, 0.0)["do_concentration"] < 1.0
    mixed = WaterColumn(surface_temp_c=18.0, bottom_temp_c=18.0)
    assert {mixed.truth(z, 0.0)["temperature"] for z in (0.0, 4.0, 10.0)} == {18.0}
