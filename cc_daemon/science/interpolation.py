"""Linear interpolation and regular sequences as the limnologists' reference computes them.

rLakeAnalyzer (the reference of `limnology`) leans on two R primitives whose edge
rules shape its answers: `stats::approx` (pairs with a missing value dropped, x
sorted, the y of equal x averaged, and no answer outside the range of x) and
`seq(from, to, by)` (a count rounded down with a 1e-10 allowance, never past
`to`). This module gives both, so that our definitions agree with the reference
to 1e-6; it knows nothing of lakes. Pure: arrays in, arrays out.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
ArrayLike = npt.ArrayLike

# R's .Machine$double.eps: a span this small relative to its ends is no span at all.
_DOUBLE_EPS = 2.220446049250313e-16


def approx(x: ArrayLike, y: ArrayLike, at: ArrayLike) -> FloatArray:
    """y interpolated linearly at `at` through the points (x, y); NaN outside the range of
    x, and NaN everywhere when fewer than two distinct x have a y (R stops there).

    Points with a missing x or y are left out, and the y of repeated x are averaged
    (R's `approx(x, y, xout)` with its defaults `rule = 1`, `ties = mean`).
    """
    xs = np.asarray(x, dtype=np.float64).ravel()
    ys = np.asarray(y, dtype=np.float64).ravel()
    out_at = np.asarray(at, dtype=np.float64)
    if xs.shape != ys.shape:
        raise ValueError("x and y must have the same length")
    keep = ~(np.isnan(xs) | np.isnan(ys))
    xs, ys = xs[keep], ys[keep]
    nodes, inverse = np.unique(xs, return_inverse=True)
    if len(nodes) < 2:
        return np.full(out_at.shape, math.nan)
    means = np.bincount(inverse, weights=ys) / np.bincount(inverse)
    found: FloatArray = np.interp(out_at, nodes, means)
    outside = (out_at < nodes[0]) | (out_at > nodes[-1]) | np.isnan(out_at)
    return np.where(outside, math.nan, found)


def regular(start: float, stop: float, step: float) -> FloatArray:
    """`start, start + step, ...` up to `stop` and never past it (R's `seq(from, to, by)`)."""
    if step <= 0:
        raise ValueError("step must be > 0")
    span = stop - start
    if span < 0:
        raise ValueError("stop must not be below start")
    if span == 0 and stop == 0:
        return np.array([stop])
    if span / max(abs(stop), abs(start)) < 100 * _DOUBLE_EPS:
        return np.array([start])
    count = int(span / step + 1e-10)
    values: FloatArray = np.minimum(start + np.arange(count + 1) * step, stop)
    return values
