"""The gridded bed: block medians interpolated to cell centres, and what is left empty.

A cell is mapped when the interpolation reaches it (inside the convex hull of
the blocks, in a triangle no side of which is longer than twice the maximum
distance: nothing is extrapolated, nor bridged across water nobody sounded) and
a kept sounding lies within the maximum distance of its centre; every other cell
stays empty (NaN), never guessed. Each cell also carries its distance to the
nearest sounding (the map's own measure of how far it is from what was
measured) and how many soundings fell in it. Rows run along y (north), columns along x (east).

Pure: arrays in, arrays out (numpy, scipy's KD-tree).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from cc_daemon.science.bathymetry import interpolate
from cc_daemon.science.bathymetry.blocks import Blocks, GridSpec, block_median

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class Grid:
    spec: GridSpec
    depth_m: FloatArray  # (ny, nx); NaN: not mapped
    distance_m: FloatArray  # (ny, nx): to the nearest sounding kept, every cell
    count: IntArray  # (ny, nx): soundings in the cell
    max_distance_m: float
    method: str
    hull_cells: int  # cells the interpolation reached, mapped or too far from a sounding

    @property
    def mapped(self) -> npt.NDArray[np.bool_]:
        result: npt.NDArray[np.bool_] = np.isfinite(self.depth_m)
        return result

    @property
    def mapped_cells(self) -> int:
        return int(np.count_nonzero(self.mapped))

    @property
    def mapped_area_m2(self) -> float:
        return self.mapped_cells * self.spec.cell_area_m2

    @property
    def covered_fraction(self) -> float:
        """Mapped cells over the cells within the survey's outline (its convex hull)."""
        return self.mapped_cells / self.hull_cells if self.hull_cells else 0.0


def max_edge_m(max_distance_m: float) -> float:
    """The longest side of a triangle the grid interpolates in: twice the maximum distance,
    so a triangle spanning two adjacent lines is used and one spanning a missed line, or
    the hull's sliver along a line sailed half-way, is not."""
    return 2.0 * max_distance_m


def inside_hull(x: FloatArray, y: FloatArray, qx: FloatArray, qy: FloatArray) -> Any:
    """Which query points lie inside the convex hull of the points (x, y)."""
    from scipy.spatial import ConvexHull, Delaunay, QhullError

    points = np.column_stack([x, y])
    centre = points.mean(axis=0)
    try:
        corners = points[ConvexHull(points - centre).vertices] - centre
        outline = Delaunay(corners)
    except QhullError:
        return np.zeros(np.shape(qx), dtype=bool)
    q = np.column_stack([np.ravel(qx), np.ravel(qy)]) - centre
    return (outline.find_simplex(q) >= 0).reshape(np.shape(qx))


def nearest_m(x: FloatArray, y: FloatArray, qx: FloatArray, qy: FloatArray) -> FloatArray:
    """The distance from each query point to the nearest of the points (x, y)."""
    from scipy.spatial import cKDTree

    centre = (float(np.mean(x)), float(np.mean(y)))
    tree = cKDTree(np.column_stack([x - centre[0], y - centre[1]]))
    distance, _ = tree.query(np.column_stack([qx - centre[0], qy - centre[1]]), k=1)
    result: FloatArray = np.asarray(distance, dtype=np.float64)
    return result


def make_grid(
    x: FloatArray,
    y: FloatArray,
    depth: FloatArray,
    spec: GridSpec,
    *,
    max_distance_m: float,
    method: str = interpolate.DEFAULT,
) -> tuple[Grid, Blocks]:
    """The bed on `spec` from the soundings kept, and the block medians it was made from."""
    blocks = block_median(x, y, depth, spec)
    predict = interpolate.fit(
        blocks.x, blocks.y, blocks.depth, method, max_edge_m=max_edge_m(max_distance_m)
    )
    gx, gy = np.meshgrid(spec.x, spec.y)
    bed = predict(gx, gy)
    distance = nearest_m(x, y, gx.ravel(), gy.ravel()).reshape(gx.shape)
    hull_cells = int(np.count_nonzero(inside_hull(blocks.x, blocks.y, gx, gy)))
    bed[distance > max_distance_m] = np.nan
    count = np.zeros(spec.nx * spec.ny, dtype=np.int64)
    count[blocks.cell] = blocks.count
    grid = Grid(
        spec=spec,
        depth_m=bed,
        distance_m=distance,
        count=count.reshape(spec.ny, spec.nx),
        max_distance_m=max_distance_m,
        method=method,
        hull_cells=hull_cells,
    )
    return grid, blocks
