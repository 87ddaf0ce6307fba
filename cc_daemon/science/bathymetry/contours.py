"""Contour lines of a gridded bed, at levels a map reader expects (contourpy).

Lines follow the grid's cell centres; an empty cell (NaN) breaks them, so no
line is drawn through water that was not mapped. contourpy is the library
matplotlib draws its own contours with, without matplotlib. Pure: arrays in,
lines (arrays of x, y) out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from cc_daemon.science.bathymetry.spacing import nice

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Contour:
    level_m: float
    lines: tuple[FloatArray, ...]  # each an (n, 2) array of x, y


def interval_m(depth: FloatArray, lines: int = 8) -> float:
    """A round contour interval giving about `lines` levels over the grid's depths."""
    finite = depth[np.isfinite(depth)]
    if len(finite) == 0:
        return 1.0
    span = float(finite.max() - finite.min())
    return nice(max(span / lines, 0.1))


def levels(depth: FloatArray, interval: float) -> list[float]:
    """Every multiple of `interval` strictly inside the grid's range of depths."""
    finite = depth[np.isfinite(depth)]
    if len(finite) == 0:
        return []
    low = math.floor(float(finite.min()) / interval) + 1
    high = math.ceil(float(finite.max()) / interval) - 1
    return [round(k * interval, 6) for k in range(low, high + 1)]


def contours(x: FloatArray, y: FloatArray, depth: FloatArray, interval: float) -> list[Contour]:
    """The contour lines of `depth` (rows along `y`, columns along `x`) every `interval`;
    none on a grid one cell wide or tall (a single line sailed: nothing to contour)."""
    import contourpy

    if depth.ndim != 2 or min(depth.shape) < 2:
        return []

    masked = np.ma.masked_invalid(depth)
    generator = contourpy.contour_generator(
        x, y, masked, line_type=contourpy.LineType.Separate, corner_mask=True
    )
    found = []
    for level in levels(depth, interval):
        lines = tuple(np.asarray(line, dtype=np.float64) for line in generator.lines(level))
        kept = tuple(line for line in lines if len(line) >= 2)
        if kept:
            found.append(Contour(level, kept))
    return found
