"""The science floor's limnology on its own: the reference's edge rules, the features
rLakeAnalyzer does not define, and each against the simulator's truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cc_daemon.science.hypsography import Hypsography
from cc_daemon.science.interpolation import approx, regular
from cc_daemon.science.limnology.density import water_density
from cc_daemon.science.limnology.features import (
    AT_EDGE,
    NO_DECREASE,
    NOT_REACHED,
    deep_chlorophyll_maximum,
    hypoxia_top,
    oxycline,
    surface_and_bottom,
)
from cc_daemon.science.limnology.metalimnion import meta_depths
from cc_daemon.science.limnology.schmidt import schmidt_stability, schmidt_stability_in
from cc_daemon.science.limnology.thermocline import thermo_depth
from cc_daemon.sim.water import WaterColumn


def test_approx_drops_missing_points_averages_ties_and_answers_nothing_outside() -> None:
    x = [0.0, 1.0, 1.0, math.nan, 3.0]
    y = [0.0, 2.0, 4.0, 100.0, 3.0]
    assert approx(x, y, [0.5, 1.0, 2.0]) == pytest.approx([1.5, 3.0, 3.0])
    assert np.isnan(approx(x, y, [-0.1, 3.1, math.nan])).all()
    assert np.isnan(approx([1.0, 1.0], [2.0, 3.0], [1.0])).all()  # one distinct x
    assert approx([3.0, 1.0], [30.0, 10.0], [2.0]) == pytest.approx([20.0])  # any order


def test_regular_never_passes_its_end() -> None:
    assert regular(0.0, 0.35, 0.1) == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert regular(0.0, 0.3, 0.1)[-1] == pytest.approx(0.3)  # 0.30000000000000004 kept at 0.3
    assert regular(0.0, 0.3, 0.1)[-1] <= 0.3
    assert list(regular(2.0, 2.0, 0.1)) == [2.0]
    with pytest.raises(ValueError, match="step"):
        regular(0.0, 1.0, 0.0)


def test_water_is_densest_near_four_degrees() -> None:
    rho = water_density(np.arange(0.0, 10.0, 0.01))
    assert 3.9 < float(np.arange(0.0, 10.0, 0.01)[np.argmax(rho)]) < 4.1
    assert math.isnan(float(water_density(math.nan)))


def test_no_thermocline_in_a_mixed_short_or_gappy_profile() -> None:
    z = [0.0, 1.0, 2.0, 3.0]
    assert math.isnan(thermo_depth([20.0, 19.8, 19.5, 19.1], z))  # 0.9 degC: mixed
    assert math.isnan(thermo_depth([20.0, 15.0], [0.0, 1.0]))
    assert math.isnan(thermo_depth([20.0, math.nan, 15.0, 14.0], z))
    assert meta_depths([20.0, 15.0], [0.0, 1.0]) == (1.0, 1.0)
    with pytest.raises(ValueError, match="unique"):
        thermo_depth([20.0, 18.0, 15.0, 12.0], [0.0, 1.0, 1.0, 2.0])


def truth_on(water: WaterColumn, name: str, step: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
    z = np.arange(0.0, water.bottom_m, step)
    return z, np.array([water.truth(d, 0.0)[name] for d in z])


def test_the_definitions_on_the_true_column_find_its_thermocline() -> None:
    """The largest density gradient of the simulator's column is shallower than its
    temperature's inflection (4.0 m): warm water's density changes faster."""
    water = WaterColumn()
    z, t = truth_on(water, "temperature", 0.01)
    found = thermo_depth(t, z, seasonal=False)
    assert found == pytest.approx(3.77, abs=0.01)
    top, bottom = meta_depths(t, z)
    assert top < found < bottom and bottom - top > 2 * water.thermocline_width_m


def test_schmidt_stability_is_zero_for_a_mixed_lake_and_grows_with_stratification() -> None:
    lake = Hypsography(
        depth_m=np.arange(0.0, 13.0),
        area_m2=250_000.0 * (1 - np.arange(0.0, 13.0) / 12) ** 1.5,
        volume_m3=np.zeros(13),
    )
    z = np.arange(0.0, 10.0, 0.25)
    mixed = schmidt_stability_in(np.full(len(z), 18.0), z, lake)
    assert mixed == pytest.approx(0.0, abs=1e-6)
    weak = schmidt_stability_in(
        [WaterColumn(surface_temp_c=16.0).truth(d, 0)["temperature"] for d in z], z, lake
    )
    strong = schmidt_stability_in([WaterColumn().truth(d, 0)["temperature"] for d in z], z, lake)
    assert 0 < weak < strong
    # The Hypsography value and the reference's bthA, bthD are one lake.
    t = [WaterColumn().truth(d, 0)["temperature"] for d in z]
    assert strong == schmidt_stability(t, z, lake.area_m2, lake.depth_m)
    with pytest.raises(ValueError, match="area at the profile's top is 0"):
        schmidt_stability(t, z, [0.0, 0.0], [0.0, 12.0])


def test_the_deep_chlorophyll_maximum_is_found_between_bins() -> None:
    water = WaterColumn(chlorophyll_max_m=3.1)
    z = np.arange(0.0, 6.0, 0.25)
    chl = [water.truth(d, 0)["chlorophyll"] for d in z]
    found = deep_chlorophyll_maximum(z, chl)
    assert found.depth_m == pytest.approx(3.1, abs=0.02)
    assert found.value == max(chl)
    # At an edge it is no subsurface maximum: the cast may have stopped above it.
    assert deep_chlorophyll_maximum(z[:10], chl[:10]).missing == AT_EDGE


def test_the_oxycline_and_the_hypoxic_water() -> None:
    water = WaterColumn(hypolimnion_do_saturation_pct=5.0)
    fine_z, fine_o = truth_on(water, "do_concentration")
    steepest = fine_z[np.argmax(-np.diff(fine_o) / np.diff(fine_z))]
    first_hypoxic = fine_z[np.argmax(fine_o < 2.0)]
    z = np.arange(0.0, 9.0, 0.25)
    o = np.array([water.truth(d, 0)["do_concentration"] for d in z])
    found = oxycline(z, o)
    assert found.depth_m == pytest.approx(steepest, abs=0.1) and found.value is not None
    assert found.value < 0
    top = hypoxia_top(z, o)
    assert top.depth_m == pytest.approx(first_hypoxic, abs=0.02) and top.value == 2.0
    # Never under 2 mg/L down to the last bin: the hypoxic water, if any, is deeper.
    assert hypoxia_top(z[:15], o[:15]).missing == NOT_REACHED
    assert hypoxia_top(z, np.full(len(z), 1.0)).depth_m == 0.0  # hypoxic from the top
    assert oxycline(z, np.linspace(5.0, 9.0, len(z))).missing == NO_DECREASE


def test_surface_and_bottom_skip_empty_bins() -> None:
    surface, bottom = surface_and_bottom([0.0, 0.25, 0.5, 0.75], [math.nan, 20.0, 19.0, math.nan])
    assert (surface.depth_m, surface.value) == (0.25, 20.0)
    assert (bottom.depth_m, bottom.value) == (0.5, 19.0)
    assert surface_and_bottom([0.0], [math.nan])[0].missing == "no_data"
