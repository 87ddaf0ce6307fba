"""What a binned profile says about the water: stratification, oxygen, chlorophyll.

The glue between `binning.Binned` and `limnology`: from a cast's binned way down
(the values at the bins' centres, empty bins left out), the thermocline (the
largest density gradient's, and the seasonal one), the metalimnion (around the
seasonal thermocline, rLakeAnalyzer's default), Schmidt stability in the lake's
hypsography, the deep chlorophyll maximum, the oxycline, the top of the hypoxic
water, and every parameter's surface and bottom values. Which parameter is the
temperature, the oxygen (mg/L) and the chlorophyll is the caller's to say
(`Roles`). A number that cannot be read is None with a short reason, never a
zero. Pure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cc_daemon.science.hypsography import Hypsography
from cc_daemon.science.limnology.features import (
    Found,
    deep_chlorophyll_maximum,
    hypoxia_top,
    oxycline,
    surface_and_bottom,
)
from cc_daemon.science.limnology.metalimnion import meta_depths
from cc_daemon.science.limnology.schmidt import schmidt_stability_in
from cc_daemon.science.limnology.thermocline import MIXED_CUTOFF_C, thermo_depth
from cc_daemon.science.profiles.binning import Binned

# Why a number is missing, as the products write it.
NO_PARAMETER = "no_parameter"  # the sonde's map has no such parameter
TOO_FEW_BINS = "too_few_bins"  # fewer than three bins with a value
MIXED = "mixed"  # temperature spans less than mixed_cutoff (1 degC): no thermocline
NO_HYPSOGRAPHY = "no_hypsography"  # Schmidt stability needs the lake's shape
NOT_FOUND = "not_found"  # the reference's rules give no answer (NaN)

QUANTITIES = (
    "thermocline_m",
    "seasonal_thermocline_m",
    "metalimnion_top_m",
    "metalimnion_bottom_m",
    "schmidt_stability_j_m2",
    "dcm_m",
    "dcm_chlorophyll",
    "oxycline_m",
    "oxycline_gradient",
    "hypoxia_top_m",
)


@dataclass(frozen=True, slots=True)
class Roles:
    """The names of the parameters that are the temperature (°C), the oxygen (mg/L) and
    the chlorophyll; None where the sonde has none."""

    temperature: str | None = "temperature"
    oxygen: str | None = "do_concentration"
    chlorophyll: str | None = "chlorophyll"


@dataclass(frozen=True, slots=True)
class Reading:
    """A profile's numbers (None where missing, with the reason in `missing`) and each
    parameter's surface and bottom values."""

    numbers: dict[str, float | None] = field(default_factory=dict)
    missing: dict[str, str] = field(default_factory=dict)
    surface: dict[str, Found] = field(default_factory=dict)
    bottom: dict[str, Found] = field(default_factory=dict)

    def put(self, name: str, value: float | None, reason: str = NOT_FOUND) -> None:
        if value is None or not math.isfinite(value):
            self.numbers[name] = None
            self.missing[name] = reason
        else:
            self.numbers[name] = float(value)


def _found(reading: Reading, depth: str, value: str | None, found: Found) -> None:
    reading.put(depth, found.depth_m, found.missing or NOT_FOUND)
    if value is not None:
        reading.put(value, found.value, found.missing or NOT_FOUND)


def _stratification(
    reading: Reading, profile: Binned, name: str | None, lake: Hypsography | None
) -> None:
    if name is None or name not in profile.count:
        for quantity in QUANTITIES[:5]:
            reading.put(quantity, None, NO_PARAMETER)
        return
    z, t = profile.present(name)
    if len(z) < 3:
        why = TOO_FEW_BINS
    elif float(np.max(t) - np.min(t)) < MIXED_CUTOFF_C:
        why = MIXED
    else:
        why = NOT_FOUND
    reading.put("thermocline_m", thermo_depth(t, z, seasonal=False), why)
    reading.put("seasonal_thermocline_m", thermo_depth(t, z), why)
    top, bottom = meta_depths(t, z) if len(z) >= 3 else (math.nan, math.nan)
    reading.put("metalimnion_top_m", top, why)
    reading.put("metalimnion_bottom_m", bottom, why)
    if lake is None:
        reading.put("schmidt_stability_j_m2", None, NO_HYPSOGRAPHY)
    elif len(z) < 2:
        reading.put("schmidt_stability_j_m2", None, TOO_FEW_BINS)
    else:
        reading.put("schmidt_stability_j_m2", schmidt_stability_in(t, z, lake))


def read_profile(profile: Binned, roles: Roles, lake: Hypsography | None = None) -> Reading:
    """The numbers of `profile` (a cast's binned way down) in a lake of hypsography
    `lake` (None: unknown; Schmidt stability then missing)."""
    reading = Reading()
    _stratification(reading, profile, roles.temperature, lake)
    if roles.chlorophyll is not None and roles.chlorophyll in profile.count:
        dcm = deep_chlorophyll_maximum(*profile.present(roles.chlorophyll))
        _found(reading, "dcm_m", "dcm_chlorophyll", dcm)
    else:
        reading.put("dcm_m", None, NO_PARAMETER)
        reading.put("dcm_chlorophyll", None, NO_PARAMETER)
    if roles.oxygen is not None and roles.oxygen in profile.count:
        z, o = profile.present(roles.oxygen)
        _found(reading, "oxycline_m", "oxycline_gradient", oxycline(z, o))
        _found(reading, "hypoxia_top_m", None, hypoxia_top(z, o))
    else:
        for quantity in ("oxycline_m", "oxycline_gradient", "hypoxia_top_m"):
            reading.put(quantity, None, NO_PARAMETER)
    for name in profile.count:
        reading.surface[name], reading.bottom[name] = surface_and_bottom(*profile.present(name))
    return reading
