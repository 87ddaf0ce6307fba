"""The metalimnion: the layer around the thermocline where density changes steeply
(rLakeAnalyzer's `meta.depths`).

Definitions (rLakeAnalyzer 1.12; Wetzel 2001):
- the density gradient of each pair of neighbouring depths is placed at the
  pair's middle, and interpolated (linearly) onto those middles and the
  thermocline's depth (`thermocline.thermo_depth`, seasonal or not);
- from the thermocline downwards, the first of those depths whose gradient is
  under `slope` (0.1 kg/m³ per m) ends the search; the bottom of the metalimnion
  is where the gradient crosses `slope` between the thermocline and that depth
  (interpolated linearly), or the deepest depth when it never falls under it;
- the top is found the same way upwards, or is the shallowest depth;
- a profile with no thermocline has no metalimnion (NaN, NaN); fewer than three
  depths give the deepest depth twice.

Where the crossing cannot be interpolated the reference falls back to a depth
of the profile chosen by an index of the interpolated grid (one shorter than the
profile when the thermocline falls on a pair's middle); that fallback is kept
as it is. Pure: arrays in, two numbers out.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from cc_daemon.science.interpolation import approx
from cc_daemon.science.limnology.thermocline import (
    MIXED_CUTOFF_C,
    as_profile,
    density_gradient,
    thermo_depth,
)

FloatArray = npt.NDArray[np.float64]

SLOPE = 0.1  # kg/m³ per m: the gradient that bounds the metalimnion


def _crossing(gradient: FloatArray, depth: FloatArray, slope: float) -> float:
    """The depth where `gradient` (a short run, in either order) equals `slope`."""
    return float(approx(gradient, depth, [slope])[0])


def _search(gradient: FloatArray, order: range, slope: float) -> int:
    """The first index in `order` whose gradient is under `slope`, else the last one."""
    for i in order:
        if gradient[i] < slope:  # a NaN is never under it
            return i
    return order[-1]


def meta_depths(
    temperature_c: npt.ArrayLike,
    depth_m: npt.ArrayLike,
    *,
    slope: float = SLOPE,
    seasonal: bool = True,
    mixed_cutoff: float = MIXED_CUTOFF_C,
) -> tuple[float, float]:
    """The metalimnion's top and bottom depths (m) in a profile of `temperature_c` (°C)
    at `depth_m` (m, unique, any order); (NaN, NaN) with no thermocline."""
    t, z = as_profile(temperature_c, depth_m)
    if np.any(np.isnan(t)):
        return math.nan, math.nan
    if len(t) < 3:
        return float(np.max(z)), float(np.max(z))
    order = np.argsort(z, kind="stable")
    t, z = t[order], z[order]
    thermocline = thermo_depth(t, z, seasonal=seasonal, mixed_cutoff=mixed_cutoff)
    if math.isnan(thermocline):
        return math.nan, math.nan
    middles = (z[:-1] + z[1:]) / 2
    grid = np.unique(np.append(middles, thermocline))
    gradient = approx(middles, density_gradient(t, z), grid)
    start = int(np.flatnonzero(grid == thermocline)[0])
    steep = not math.isnan(gradient[start]) and gradient[start] > slope

    down = _search(gradient, range(start, len(grid)), slope)
    bottom = float(grid[down]) if gradient[down] < slope else float(z[-1])
    if down - start >= 1 and steep:
        bottom = _crossing(gradient[start : down + 1], grid[start : down + 1], slope)
    if math.isnan(bottom):
        bottom = float(z[len(grid) - 1])
    up = _search(gradient, range(start, -1, -1), slope)
    top = float(grid[up]) if gradient[up] < slope else float(z[0])
    if start - up >= 1 and steep:
        top = _crossing(gradient[up : start + 1], grid[up : start + 1], slope)
    if math.isnan(top):
        top = float(z[up])
    return top, bottom
