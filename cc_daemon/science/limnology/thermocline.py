"""The thermocline: where density changes fastest with depth (rLakeAnalyzer's `thermo.depth`).

Definitions (Read et al. 2011, rLakeAnalyzer 1.12):
- the density gradient between each pair of neighbouring depths, from the water
  density of `density`;
- the thermocline lies between the pair with the largest gradient, placed
  between them by the curvature of the gradient on either side (each side's
  depth step over its change of gradient weights the other end), which gives a
  depth finer than the spacing of the profile;
- the *seasonal* thermocline is the deepest local maximum of the gradient that
  is at least 15 % of the largest one and at least `min_gradient` (0.1 kg/m³/m),
  and lies more than one pair below the largest; otherwise it is the thermocline
  itself, and it is never shallower than it;
- a profile with a missing temperature, fewer than three depths, or a range of
  temperature under `mixed_cutoff` (1 °C) has no thermocline (NaN).

Two of the reference's rules look accidental and are kept because they change
answers: the search for local maxima also takes the first pair as a maximum when
the second is larger (and judges it by the second's gradient), and never takes
the last pair. Pure: arrays in, a number out.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from cc_daemon.science.limnology.density import water_density

FloatArray = npt.NDArray[np.float64]

MIXED_CUTOFF_C = 1.0  # under this range of temperature the column is mixed
MIN_GRADIENT = 0.1  # kg/m³ per m: the least gradient a seasonal thermocline may have
_PEAK_FRACTION = 0.15  # of the largest gradient: the least a seasonal peak may have


def density_gradient(temperature_c: FloatArray, depth_m: FloatArray) -> FloatArray:
    """The density gradient (kg/m³ per m) between each pair of neighbouring depths."""
    rho = water_density(temperature_c)
    gradient: FloatArray = np.diff(rho) / np.diff(depth_m)
    return gradient


def placed_between(depth_m: FloatArray, gradient: FloatArray, i: int) -> float:
    """The depth of a gradient's maximum at pair `i` (between depths i and i + 1): the
    pair's middle, or where the curvature either side places it when both neighbouring
    pairs exist (Read et al. 2011)."""
    middle = float((depth_m[i] + depth_m[i + 1]) / 2)
    if not 0 < i < len(gradient) - 1:
        return middle
    with np.errstate(divide="ignore", invalid="ignore"):
        below = -(depth_m[i + 1] - depth_m[i]) / (gradient[i + 1] - gradient[i])
        above = (depth_m[i] - depth_m[i - 1]) / (gradient[i] - gradient[i - 1])
        if math.isinf(below) or math.isinf(above):  # a NaN passes, as in the reference
            return middle
        total = below + above
        return float(depth_m[i + 1] * (below / total) + depth_m[i] * (above / total))


def _peaks(gradient: FloatArray, threshold: float) -> list[int]:
    """The pairs that are local maxima of the gradient above `threshold` (the
    reference's rule: see the module's docstring)."""
    found: list[int] = []
    if len(gradient) >= 2 and gradient[1] > gradient[0] and gradient[1] > threshold:
        found.append(0)
    for j in range(1, len(gradient) - 1):
        here = gradient[j]
        if here > gradient[j - 1] and here >= gradient[j + 1] and here > threshold:
            found.append(j)
    return found


def as_profile(
    temperature_c: npt.ArrayLike, depth_m: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """A profile's temperatures and depths as arrays of one length (ValueError if not)."""
    t = np.asarray(temperature_c, dtype=np.float64)
    z = np.asarray(depth_m, dtype=np.float64)
    if len(t) != len(z):
        raise ValueError("temperature and depth must have the same length")
    return t, z


def thermo_depth(
    temperature_c: npt.ArrayLike,
    depth_m: npt.ArrayLike,
    *,
    seasonal: bool = True,
    min_gradient: float = MIN_GRADIENT,
    mixed_cutoff: float = MIXED_CUTOFF_C,
) -> float:
    """The thermocline's depth (m) in a profile of `temperature_c` (°C) at `depth_m` (m,
    unique, in the order given); NaN where there is none (see the module's docstring).

    `seasonal`: the seasonal thermocline (the deepest distinct gradient maximum) rather
    than the largest gradient's. Raises ValueError on repeated depths.
    """
    t, z = as_profile(temperature_c, depth_m)
    if np.any(np.isnan(z)):
        raise ValueError("every depth must be a number")
    if np.any(np.isnan(t)) or len(t) < 3:
        return math.nan
    if float(np.max(t) - np.min(t)) < mixed_cutoff:
        return math.nan
    if len(np.unique(z)) != len(z):
        raise ValueError("depths must be unique")
    gradient = density_gradient(t, z)
    largest = int(np.argmax(gradient))
    thermocline = placed_between(z, gradient, largest)
    if not seasonal:
        return thermocline
    peaks = _peaks(gradient, max(_PEAK_FRACTION * float(gradient[largest]), min_gradient))
    deepest = peaks[-1] if peaks else largest
    if deepest <= largest + 1:
        return thermocline
    return max(placed_between(z, gradient, deepest), thermocline)
