"""The interpolators that fill the grid between the lines, from the block medians.

Three of scipy's, each a function of the block medians (x, y, depth) that
returns a depth at any point, NaN outside the convex hull of the blocks (none of
them extrapolates):

- `linear`: Delaunay triangles, a plane on each (`LinearNDInterpolator`);
- `cubic`: Clough-Tocher, a smooth (C1) cubic on each triangle
  (`CloughTocher2DInterpolator`);
- `thin-plate`: a thin-plate spline fitted to the `neighbors` nearest blocks of
  each point (`RBFInterpolator`), the local form of verde's `Spline`.

Which one the products use is chosen by figures on the simulator's true bed
(accuracy, time; docs/maps.md): `DEFAULT`. Pure: arrays in, arrays out.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
Predictor = Callable[[FloatArray, FloatArray], FloatArray]

METHODS = ("linear", "cubic", "thin-plate")
DEFAULT = "linear"
RBF_NEIGHBORS = 32


def fit(
    x: FloatArray,
    y: FloatArray,
    depth: FloatArray,
    method: str = DEFAULT,
    *,
    max_edge_m: float | None = None,
) -> Predictor:
    """An interpolator of `depth` at (`x`, `y`) by `method`; it needs three points or more
    that are not on one line (ValueError otherwise). With `max_edge_m`, a point in a
    triangle with a longer side gets NaN: such a triangle spans water nobody sounded (the
    convex hull's sliver along a line sailed half-way, a missed line), and what it would
    give there is a guess, however near one of its corners a sounding is."""
    from scipy.interpolate import (
        CloughTocher2DInterpolator,
        LinearNDInterpolator,
        RBFInterpolator,
    )
    from scipy.spatial import Delaunay, QhullError

    if method not in METHODS:
        raise ValueError(f"interpolation {method!r}: one of {', '.join(METHODS)}")
    points = np.column_stack([x, y])
    if len(points) < 3:
        raise ValueError(f"{len(points)} blocks of soundings: too few to interpolate")
    # Centred: the triangulation's arithmetic at UTM's 10^6 m loses centimetres.
    centre = points.mean(axis=0)
    try:
        triangles = Delaunay(points - centre)
    except QhullError as exc:
        raise ValueError("the soundings lie on one line: nothing to interpolate between") from exc
    _barycentric(triangles)
    if method == "linear":
        inner: Callable[[FloatArray], FloatArray] = LinearNDInterpolator(triangles, depth)
    elif method == "cubic":
        inner = CloughTocher2DInterpolator(triangles, depth)
    else:
        spline = RBFInterpolator(
            points - centre, depth, neighbors=min(RBF_NEIGHBORS, len(points)),
            kernel="thin_plate_spline", degree=1,
        )  # fmt: skip

        def inner(q: FloatArray) -> FloatArray:
            # Within the hull only: a spline would extrapolate beyond it.
            result: FloatArray = np.full(len(q), np.nan)
            inside = triangles.find_simplex(q) >= 0
            if inside.any():
                result[inside] = spline(q[inside])
            return result

    too_long = _long_sides(triangles, max_edge_m)

    def predict(qx: FloatArray, qy: FloatArray) -> FloatArray:
        q = np.column_stack([np.ravel(qx), np.ravel(qy)]) - centre
        found = np.asarray(inner(q), dtype=np.float64)
        if too_long is not None:
            simplex = triangles.find_simplex(q)
            found[(simplex >= 0) & too_long[np.maximum(simplex, 0)]] = np.nan
        result: FloatArray = found.reshape(np.shape(qx))
        return result

    return predict


def _long_sides(triangles: Any, max_edge_m: float | None) -> npt.NDArray[np.bool_] | None:
    """Which triangles have a side longer than `max_edge_m` (None: no limit)."""
    if max_edge_m is None:
        return None
    corners = triangles.points[triangles.simplices]
    sides = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
    result: npt.NDArray[np.bool_] = sides.max(axis=1) > max_edge_m
    return result


def _barycentric(triangles: Any) -> None:
    """Give `triangles` their barycentric transforms, computed here at once: scipy makes
    them lazily one triangle at a time, which took 15 s for 80,000 triangles here (0.02 s
    so), and every lookup needs them. Where scipy keeps them elsewhere, it does so itself.
    """
    if getattr(triangles, "_transform", "absent") is not None:
        return
    corners = triangles.points[triangles.simplices]  # (n, 3, 2)
    last = corners[:, 2, :]
    a, b = corners[:, 0, :] - last, corners[:, 1, :] - last
    det = a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]
    flat = np.abs(det) <= 1e-12 * np.maximum(np.abs(a).sum(1) * np.abs(b).sum(1), 1e-300)
    det = np.where(flat, np.nan, det)
    transform = np.empty((len(corners), 3, 2))
    transform[:, 0, 0], transform[:, 0, 1] = b[:, 1] / det, -b[:, 0] / det
    transform[:, 1, 0], transform[:, 1, 1] = -a[:, 1] / det, a[:, 0] / det
    transform[:, 2, :] = last
    triangles._transform = transform
