"""Schmidt stability: the work needed to mix a stratified lake, per unit of its surface
(rLakeAnalyzer's `schmidt.stability`; Schmidt 1928, Hutchinson 1957, Idso 1973).

    S = g / A0 * sum over layers of rho(z) * (z - z_v) * A(z) * dz

with layers every `dz` = 0.1 m from the profile's top to the deepest of the
profile and the hypsography, the density `rho` and the area `A` interpolated
linearly at each layer, `z_v` the depth of the lake's centre of volume
(sum z A / sum A), `A0` the area at the profile's top and g = 9.81 m/s². Fresh
water (salinity 0).

How the profile and the lake are joined (the reference's rules, kept):
- a lake deeper than the profile's last depth takes that last temperature
  down to its deepest depth (a cast that stops above the bed assumes the water
  below it is the water it last saw);
- a profile deeper than the hypsography closes the lake with an area of 0 there;
- a hypsography starting above the profile's top takes the top temperature up
  to it; depths above the surface (negative) are dropped.

The lake's shape comes from its hypsography (`science.hypsography.Hypsography`,
or rLakeAnalyzer's `bthD`, `bthA`): the survey's bathymetry makes it. Pure.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from cc_daemon.science.hypsography import Hypsography
from cc_daemon.science.interpolation import approx, regular
from cc_daemon.science.limnology.density import water_density
from cc_daemon.science.limnology.thermocline import as_profile

GRAVITY_M_S2 = 9.81
LAYER_M = 0.1


def schmidt_stability(
    temperature_c: npt.ArrayLike,
    depth_m: npt.ArrayLike,
    area_m2: npt.ArrayLike,
    area_depth_m: npt.ArrayLike,
) -> float:
    """Schmidt stability (J/m²) of a profile of `temperature_c` (°C) at `depth_m` (m,
    increasing) in a lake whose horizontal area is `area_m2` (m²) at `area_depth_m` (m,
    increasing; rLakeAnalyzer's `bthA`, `bthD`). NaN where the lake's areas do not
    reach the profile's top. Raises ValueError when the area at the top is 0."""
    t, z = as_profile(temperature_c, depth_m)
    area = np.asarray(area_m2, dtype=np.float64)
    at = np.asarray(area_depth_m, dtype=np.float64)
    if len(area) != len(at):
        raise ValueError("the areas and their depths must have the same length")
    if len(t) == 0:
        raise ValueError("no temperature to judge the stability of")
    if np.min(at) < 0:  # above the surface: dropped, with the surface's area interpolated
        kept = at[at >= 0]
        surface = kept if np.any(at == 0) else np.append(0.0, kept)
        area, at = approx(at, area, surface), surface
    lake_bottom = float(np.max(at))
    if lake_bottom > z[-1]:
        t, z = np.append(t, t[-1]), np.append(z, lake_bottom)
    elif lake_bottom < z[-1]:
        at, area = np.append(at, z[-1]), np.append(area, 0.0)
    if np.min(at) < z[0]:
        t, z = np.append(t[0], t), np.append(np.min(at), z)
    top_area = float(area[int(np.argmin(z))])
    if top_area == 0:
        raise ValueError("the lake's area at the profile's top is 0: check the hypsography")
    layers = regular(float(np.min(z)), float(np.max(z)), LAYER_M)
    rho = approx(z, water_density(t), layers)
    areas = approx(at, area, layers)
    centre = float(layers @ areas / np.sum(areas))
    return float(rho @ ((layers - centre) * areas) * LAYER_M * GRAVITY_M_S2 / top_area)


def schmidt_stability_in(
    temperature_c: npt.ArrayLike, depth_m: npt.ArrayLike, lake: Hypsography
) -> float:
    """`schmidt_stability` in the lake a `Hypsography` describes."""
    return schmidt_stability(temperature_c, depth_m, lake.area_m2, lake.depth_m)
