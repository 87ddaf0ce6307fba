"""A cast made into profiles: split, loop edit, lag correction, binning, and what is read
from them, on hand-made series and on simulated casts judged against the water's truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cc_daemon.science.limnology.density import water_density
from cc_daemon.science.limnology.thermocline import thermo_depth
from cc_daemon.science.profiles.binning import bin_average
from cc_daemon.science.profiles.casts import loop_edit, motion, speed, split
from cc_daemon.science.profiles.derived import MIXED, NO_HYPSOGRAPHY, Roles, read_profile
from cc_daemon.science.profiles.lag import correct_lag
from cc_daemon.science.profiles.local import local_line, local_slope
from cc_daemon.science.profiles.process import Processed, Series, Settings, process
from cc_daemon.sim.profilecast import CastShape, simulated_cast
from cc_daemon.sim.water import LAG_S, WaterColumn

COLUMNS = {
    "simulator's": WaterColumn(),
    "shallower": WaterColumn(thermocline_m=2.5),
    "sharper": WaterColumn(thermocline_width_m=0.3),
    "weaker": WaterColumn(surface_temp_c=20.0),
}
MIXED_COLUMN = WaterColumn(surface_temp_c=18.0, bottom_temp_c=18.0)
SETTINGS = Settings(response_s=LAG_S)


def true_thermocline(water: WaterColumn) -> float:
    """rLakeAnalyzer's definition on the true column, a millimetre apart."""
    z = np.arange(0.0, water.bottom_m, 0.001)
    rho = water_density([water.truth(d, 0.0)["temperature"] for d in z])
    i = int(np.argmax(np.diff(rho)))
    return float(z[i] + z[i + 1]) / 2


def cast(water: WaterColumn, seed: int, **shape: float) -> tuple[Series, Processed]:
    series = simulated_cast(CastShape(**shape), water, seed=seed)
    return series, process(series, SETTINGS)


# ------------------------------------------------------------------ the way down and up


def test_the_ways_are_split_at_the_deepest_line_out() -> None:
    t = np.arange(10.0)
    line = np.array([0.0, 0.0, 1.0, 2.0, 3.0, 3.0, 3.0, 2.0, 1.0, 0.0])
    ways = split(t, motion(line, line))
    assert list(ways.down) == [0, 1, 2, 3, 4] and list(ways.up) == [6, 7, 8, 9]


def test_the_loop_edit_drops_the_soak_standing_still_and_water_sampled_twice() -> None:
    t = np.arange(14.0)
    # Down to the soak depth, held, on down; a wave lifts the probe at 9-10 s.
    z = np.array([0.0, 0.25, 0.5, 0.5, 0.5, 0.75, 1.0, 1.25, 1.5, 1.4, 1.45, 1.75, 2.0, 2.0])
    soaking = np.array([False, True, True, True, True] + [False] * 9)
    way = np.arange(13)
    kept = loop_edit(way, z, speed(t, z), soaking=soaking)
    assert list(kept) == [5, 6, 7, 8, 11, 12]  # after the soak; not 9, 10 (passed water)
    # Without a soak label the standstill at 0.5 m is still dropped.
    assert 3 not in loop_edit(way, z, speed(t, z))
    # A stepped cast stands at each level on purpose.
    stepped = np.array([0.0, 1.0, 1.0, 1.01, 0.99, 2.0, 2.0, 2.0, 1.5, 3.0])
    kept = loop_edit(np.arange(10), stepped, speed(np.arange(10.0), stepped), stepped=True)
    # The rise to 1.5 m dropped, and the reading as it began (its speed is centred).
    assert list(kept) == [0, 1, 2, 3, 4, 5, 6, 9]


def test_a_simulated_soak_is_left_out_of_the_profile() -> None:
    series, done = cast(WaterColumn(), 3, soak_s=20.0, soak_depth_m=0.5)
    assert series.soaking is not None and series.soaking.sum() >= 19
    last_soak = int(np.flatnonzero(series.soaking)[-1])
    assert done.down_readings.min() > last_soak


# ------------------------------------------------------------------ lag and lines


def first_order(t: np.ndarray, x: np.ndarray, tau: float) -> np.ndarray:
    """A first-order sensor's reading of `x` (finely sampled), exactly integrated."""
    y = np.empty_like(x)
    y[0] = x[0]
    for i in range(1, len(x)):
        y[i] = y[i - 1] + (x[i] - y[i - 1]) * (1 - math.exp(-(t[i] - t[i - 1]) / tau))
    return y


def test_the_inverse_restores_a_lagged_gradient_and_the_shift_only_moves_it() -> None:
    fine = np.arange(0.0, 80.0, 0.01)
    water = 20.0 - 8.0 / (1.0 + np.exp(-(fine - 40.0) / 4.0))  # a front passing in ~16 s
    sensed = first_order(fine, water, 8.0)
    t, y, x = fine[::100], sensed[::100], water[::100]  # read once a second
    inside = (t > 10) & (t < 70)
    lagged = np.max(np.abs(y - x)[inside])
    inverse = np.max(np.abs(correct_lag(t, y, 8.0) - x)[inside])
    shifted = np.max(np.abs(correct_lag(t, y, 8.0, method="shift") - x)[inside])
    assert lagged > 1.5 and inverse < 0.1 < 0.5 < shifted < lagged
    assert np.array_equal(correct_lag(t, y, 0.0), y)
    assert np.array_equal(correct_lag(t, y, 8.0, method="none"), y)
    gappy = y.copy()
    gappy[30] = math.nan
    corrected = correct_lag(t, gappy, 8.0)
    assert math.isnan(corrected[30]) and np.isfinite(corrected[29]) and np.isfinite(corrected[31])


def test_local_lines_average_noise_out_of_a_steady_motion() -> None:
    t = np.arange(0.0, 60.0)
    rng = np.random.default_rng(1)
    z = 0.125 * t + rng.normal(0.0, 0.01, len(t))
    line = local_line(t, z, 4)
    assert np.std(line - 0.125 * t) < 0.6 * np.std(z - 0.125 * t)
    assert local_slope(t, z, 3)[30] == pytest.approx(0.125, abs=0.01)
    assert math.isnan(local_slope([0.0], [1.0], 2)[0])


# ------------------------------------------------------------------ bins


def test_bins_hold_count_mean_spread_and_flag_the_thin_ones() -> None:
    z = [0.05, -0.1, 0.24, 0.3, 0.74, 0.76]
    v = {"t": [1.0, 3.0, 5.0, 7.0, 9.0, math.nan]}
    binned = bin_average(z, v, 0.25, min_count=2)
    assert list(binned.depth_m) == [0.0, 0.25, 0.5, 0.75]
    assert list(binned.count["t"]) == [2, 2, 0, 1]
    assert binned.mean["t"][:2] == pytest.approx([2.0, 6.0])
    assert binned.std["t"][0] == pytest.approx(math.sqrt(2.0))
    assert math.isnan(binned.mean["t"][2]) and math.isnan(binned.std["t"][3])  # never a 0
    assert list(binned.few["t"]) == [False, False, True, True]


def test_a_bin_value_is_the_profile_at_its_centre_not_where_its_readings_were() -> None:
    z = np.array([0.02, 0.06, 0.27, 0.31, 0.52, 0.56, 0.77, 0.81])  # all off-centre
    t = 24.0 - 4.0 * z  # a thermocline's 4 degC/m
    binned = bin_average(z, {"t": t}, 0.25)
    assert binned.mean["t"] == pytest.approx(24.0 - 4.0 * (binned.depth_m + 0.04))
    assert binned.value["t"] == pytest.approx(24.0 - 4.0 * binned.depth_m)
    assert binned.reading_depth_m["t"] == pytest.approx(binned.depth_m + 0.04)


# ------------------------------------------------------------------ simulated casts


@pytest.mark.parametrize("name", list(COLUMNS))
def test_the_thermocline_of_the_binned_way_down_is_the_waters(name: str) -> None:
    water = COLUMNS[name]
    truth = true_thermocline(water)
    for seed in range(5):
        _, done = cast(water, seed)
        z, t = done.down.present("temperature")
        assert thermo_depth(t, z, seasonal=False) == pytest.approx(truth, abs=0.15), seed


def test_a_mixed_column_has_no_thermocline() -> None:
    for seed in range(5):
        _, done = cast(MIXED_COLUMN, seed)
        reading = read_profile(done.down, Roles())
        assert reading.numbers["thermocline_m"] is None
        assert reading.missing["thermocline_m"] == MIXED
        assert reading.missing["schmidt_stability_j_m2"] == NO_HYPSOGRAPHY


def rmse(done: Processed, water: WaterColumn, name: str) -> float:
    z, values = done.down.present(name)
    return math.sqrt(
        np.mean([(v - water.truth(d, 0.0)[name]) ** 2 for d, v in zip(z, values, strict=True)])
    )


def test_the_correction_brings_both_ways_onto_the_water() -> None:
    water = WaterColumn()
    series = simulated_cast(CastShape(descent_m_s=0.25), water, seed=2)
    corrected = process(series, SETTINGS)
    raw = process(series, Settings(response_s=LAG_S, method="none"))
    for name, limit in (("temperature", 0.1), ("do_concentration", 0.2)):
        assert rmse(corrected, water, name) < limit < rmse(raw, water, name)

    # Down and up raw differ by degrees in the thermocline; corrected, they agree.
    def apart(done: Processed) -> float:
        shared = (done.down.count["temperature"] > 0) & (done.up.count["temperature"] > 0)
        gap = done.down.value["temperature"][shared] - done.up.value["temperature"][shared]
        return float(np.max(np.abs(gap)))

    assert apart(raw) > 2.0 and apart(corrected) < 0.5


def test_a_stepped_cast_is_read_at_its_levels() -> None:
    water = WaterColumn()
    series = simulated_cast(CastShape(step_m=1.0, dwell_s=10.0, depth_m=6.0), water, seed=4)
    done = process(series, Settings(response_s=LAG_S, stepped=True))
    z, t = done.down.present("temperature")
    assert {1.0, 2.0, 3.0, 4.0, 5.0, 6.0} <= set(np.round(z, 2))
    for depth, value in zip(z, t, strict=True):
        if depth in (2.0, 5.0):  # at the levels, many readings of settled water
            assert value == pytest.approx(water.truth(depth, 0.0)["temperature"], abs=0.05)
