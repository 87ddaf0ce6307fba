"""What limnologists read off a binned profile beyond rLakeAnalyzer's definitions: the deep
chlorophyll maximum, the oxycline, the top of the hypoxic water, surface and bottom.

Definitions (docs/profiles.md gives them with the figures measured):
- **deep chlorophyll maximum** (DCM): the depth of the largest chlorophyll in the
  profile, placed between the bins by the parabola through it and its two
  neighbours; none when the largest is the shallowest or the deepest value (a
  maximum at an edge is not a subsurface maximum: the cast may have missed it);
- **oxycline**: the depth where oxygen falls fastest with depth, placed between
  the bins of the steepest step as `thermocline` places the thermocline (by the
  curvature of the gradient on either side); none where oxygen never falls;
- **hypoxia**: the depth below which oxygen is under a threshold (2 mg/L) down to
  the deepest value: interpolated linearly where it crosses; none when the
  deepest value is not under it (the hypoxic water, if any, is deeper);
- **surface** and **bottom** values: the shallowest and the deepest values.

Each answer is a `Found`: a depth and a value, or None and the reason (a short
word the products write in their `missing` column). Pure: arrays in.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from cc_daemon.science.limnology.thermocline import placed_between

FloatArray = npt.NDArray[np.float64]

HYPOXIA_MG_L = 2.0

# Reasons, as the products write them.
NO_DATA = "no_data"  # too few values (fewer than three for an extremum or a gradient)
AT_EDGE = "at_edge"  # the chlorophyll maximum is the shallowest or the deepest value
NO_DECREASE = "no_decrease"  # oxygen never falls with depth
NOT_REACHED = "not_reached"  # the deepest value is not hypoxic


class Found(NamedTuple):
    """A depth (m) and the value there, or None for both and `missing`'s reason."""

    depth_m: float | None
    value: float | None
    missing: str | None = None


def _missing(reason: str) -> Found:
    return Found(None, None, reason)


def _finite(depth_m: npt.ArrayLike, values: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    z = np.asarray(depth_m, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if z.shape != v.shape:
        raise ValueError("depths and values must have the same length")
    keep = np.isfinite(z) & np.isfinite(v)
    order = np.argsort(z[keep], kind="stable")
    return z[keep][order], v[keep][order]


def deep_chlorophyll_maximum(depth_m: npt.ArrayLike, chlorophyll: npt.ArrayLike) -> Found:
    """The DCM's depth and its chlorophyll (the largest value measured, not the
    parabola's peak)."""
    z, c = _finite(depth_m, chlorophyll)
    if len(z) < 3:
        return _missing(NO_DATA)
    i = int(np.argmax(c))
    if i in (0, len(z) - 1):
        return _missing(AT_EDGE)
    (z0, z1, z2), (c0, c1, c2) = z[i - 1 : i + 2], c[i - 1 : i + 2]
    # The vertex of the parabola through the three points (uneven spacing allowed).
    numerator = (z1 - z0) ** 2 * (c1 - c2) - (z1 - z2) ** 2 * (c1 - c0)
    denominator = (z1 - z0) * (c1 - c2) - (z1 - z2) * (c1 - c0)
    depth = float(z1 - 0.5 * numerator / denominator) if denominator != 0 else float(z1)
    return Found(min(max(depth, float(z0)), float(z2)), float(c1))


def oxycline(depth_m: npt.ArrayLike, oxygen: npt.ArrayLike) -> Found:
    """The oxycline's depth, and the oxygen gradient there (mg/L per m, negative)."""
    z, o = _finite(depth_m, oxygen)
    if len(z) < 3:
        return _missing(NO_DATA)
    falling = -np.diff(o) / np.diff(z)
    i = int(np.argmax(falling))
    if falling[i] <= 0:
        return _missing(NO_DECREASE)
    return Found(placed_between(z, falling, i), -float(falling[i]))


def hypoxia_top(
    depth_m: npt.ArrayLike, oxygen: npt.ArrayLike, threshold: float = HYPOXIA_MG_L
) -> Found:
    """The depth below which oxygen stays under `threshold` down to the deepest value,
    and the threshold itself."""
    z, o = _finite(depth_m, oxygen)
    if len(z) == 0:
        return _missing(NO_DATA)
    above = np.flatnonzero(o >= threshold)
    if len(above) == 0:
        return Found(float(z[0]), threshold)  # hypoxic from the shallowest value down
    last = int(above[-1])
    if last == len(z) - 1:
        return _missing(NOT_REACHED)
    (z0, z1), (o0, o1) = z[last : last + 2], o[last : last + 2]
    return Found(float(z0 + (z1 - z0) * (o0 - threshold) / (o0 - o1)), threshold)


def surface_and_bottom(depth_m: npt.ArrayLike, values: npt.ArrayLike) -> tuple[Found, Found]:
    """The shallowest and the deepest value with their depths."""
    z, v = _finite(depth_m, values)
    if len(z) == 0:
        return _missing(NO_DATA), _missing(NO_DATA)
    return Found(float(z[0]), float(v[0])), Found(float(z[-1]), float(v[-1]))
