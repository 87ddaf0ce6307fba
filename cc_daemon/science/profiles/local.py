"""Least-squares lines through each reading and its neighbours in time.

The lag correction needs each reading's rate of change, and the depth of each
reading is better known from the probe's smooth motion than from one noisy
pressure reading: both come from a straight line fitted, by least squares, to the
readings within `window` of each (in index, clipped at the ends; missing values
left out). Pure: arrays in, arrays out.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def _window_sum(values: FloatArray, window: int) -> FloatArray:
    """The sum of `values` over indices i - window .. i + window (clipped at the ends)."""
    padded = np.concatenate(([0.0], np.cumsum(values)))
    index = np.arange(len(values))
    high = np.minimum(index + window + 1, len(values))
    low = np.maximum(index - window, 0)
    found: FloatArray = padded[high] - padded[low]
    return found


def _fits(
    time_s: npt.ArrayLike, values: npt.ArrayLike, window: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Each reading's fitted line as (slope, value at the reading's time, count used)."""
    if window < 1:
        raise ValueError("a window holds at least one reading on either side")
    t = np.asarray(time_s, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    valid = np.isfinite(y) & np.isfinite(t)
    if not np.any(valid):
        nan = np.full(len(y), math.nan)
        return nan, nan, np.zeros(len(y))
    # Times from the first valid one, so the sums of squares lose no precision.
    tc = np.where(valid, t - t[valid][0], 0.0)
    yc = np.where(valid, y, 0.0)
    n = _window_sum(valid.astype(np.float64), window)
    st, sy = _window_sum(tc, window), _window_sum(yc, window)
    stt, sty = _window_sum(tc * tc, window), _window_sum(tc * yc, window)
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = stt - st * st / n
        slope = np.where((n >= 2) & (spread > 0), (sty - st * sy / n) / spread, math.nan)
        value = sy / n + slope * (tc - st / n)
    return slope, value, n


def local_slope(time_s: npt.ArrayLike, values: npt.ArrayLike, window: int) -> FloatArray:
    """The slope (per second) of the line through each reading's window; NaN where
    fewer than two readings with a value are in it."""
    return _fits(time_s, values, window)[0]


def local_line(time_s: npt.ArrayLike, values: npt.ArrayLike, window: int) -> FloatArray:
    """The line through each reading's window, at the reading's time: `values` with
    their noise averaged out where they change linearly in time (a probe lowered at a
    constant speed). Where the line cannot be drawn, the value as it is."""
    y = np.asarray(values, dtype=np.float64)
    _, value, _ = _fits(time_s, y, window)
    found: FloatArray = np.where(np.isfinite(value), value, y)
    return found
