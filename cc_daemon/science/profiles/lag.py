"""Correcting a sensor's first-order lag: what the water was, from what the sensor read.

A first-order sensor with response time tau reads y where dy/dt = (x - y) / tau:
the water's value is x = y + tau dy/dt. Two corrections:

- `inverse` (the one the products use): x = y + tau * s, with s the least-squares
  slope of y over the readings within `window` of each (seven by default,
  `local.local_slope`), so the slope is not one difference of two noisy readings:
  a reading's noise grows about tau / (sqrt(28) dt) times over seven readings dt
  apart, against sqrt(2) tau / dt for one difference. It restores the shape of a gradient, not
  only its place;
- `shift`: x(t) = y(t + tau), the reading tau seconds later (what CTD software
  calls aligning a sensor); exact for a steady ramp, it leaves a gradient as
  smeared as the sensor saw it.

docs/profiles.md gives the figures that chose `inverse` (benchmarks/profiles.py).
A response time of 0 leaves the values as they are. Values are NaN where they
are missing or cannot be corrected (fewer than two readings in a window, the
last tau seconds of a shift). Pure: arrays in, an array out.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import numpy.typing as npt

from cc_daemon.science.profiles.local import local_slope

FloatArray = npt.NDArray[np.float64]
Method = Literal["inverse", "shift", "none"]
METHODS: tuple[Method, ...] = ("inverse", "shift", "none")
WINDOW = 3  # readings on either side of each in the slope's fit (seven in all)


def correct_lag(
    time_s: npt.ArrayLike,
    values: npt.ArrayLike,
    response_s: float,
    *,
    method: Method = "inverse",
    window: int = WINDOW,
) -> FloatArray:
    """`values` (in time order) as the water held them, for a sensor of `response_s`."""
    y = np.asarray(values, dtype=np.float64)
    if response_s < 0:
        raise ValueError("a response time is >= 0 s")
    if response_s == 0 or method == "none":
        return y.copy()
    t = np.asarray(time_s, dtype=np.float64)
    if method == "inverse":
        corrected: FloatArray = y + response_s * local_slope(t, y, window)
        return np.where(np.isfinite(y), corrected, math.nan)
    valid = np.isfinite(y)
    if np.count_nonzero(valid) < 2:
        return np.full(len(y), math.nan)
    return np.interp(t + response_s, t[valid], y[valid], left=math.nan, right=math.nan)
