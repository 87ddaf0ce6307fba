"""The block median: the soundings in each cell of a grid reduced to one.

A single-beam survey samples densely along its lines and not at all between
them; interpolating every sounding would weigh a line by its soundings and bend
the surface to their noise. The median of each cell's depths (robust to what the
quality control let through) placed at the median of its soundings' positions
(not the cell's centre: on a slope, a line through a cell's edge would otherwise
shift its depth by half a cell) is what the interpolators get, as verde's
`BlockReduce` does with `np.median`.

Pure: arrays in, arrays out (numpy).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

MAD_SCALE = 1.4826  # MAD to a normal distribution's standard deviation


@dataclass(frozen=True, slots=True)
class GridSpec:
    """A regular grid of `nx` x `ny` square cells of `cell_m`, its lower-left corner at
    (`x0`, `y0`) (metres, projected); cell (i, j) is column i, row j."""

    x0: float
    y0: float
    cell_m: float
    nx: int
    ny: int

    @classmethod
    def covering(cls, x: FloatArray, y: FloatArray, cell_m: float) -> GridSpec:
        """The smallest grid of `cell_m` cells, their edges on multiples of `cell_m`, that
        holds every point."""
        if cell_m <= 0:
            raise ValueError(f"cell size {cell_m} m: must be > 0")
        x0 = np.floor(x.min() / cell_m) * cell_m
        y0 = np.floor(y.min() / cell_m) * cell_m
        nx = int(np.floor((x.max() - x0) / cell_m)) + 1
        ny = int(np.floor((y.max() - y0) / cell_m)) + 1
        return cls(float(x0), float(y0), cell_m, nx, ny)

    @property
    def x(self) -> FloatArray:
        """The cells' centres, east."""
        return (self.x0 + (np.arange(self.nx) + 0.5) * self.cell_m).astype(np.float64)

    @property
    def y(self) -> FloatArray:
        """The cells' centres, north."""
        return (self.y0 + (np.arange(self.ny) + 0.5) * self.cell_m).astype(np.float64)

    @property
    def cell_area_m2(self) -> float:
        return self.cell_m * self.cell_m

    def index(self, x: FloatArray, y: FloatArray) -> IntArray:
        """Each point's cell as one number (row * nx + column); -1 outside the grid."""
        i = np.floor((x - self.x0) / self.cell_m).astype(np.int64)
        j = np.floor((y - self.y0) / self.cell_m).astype(np.int64)
        inside = (i >= 0) & (i < self.nx) & (j >= 0) & (j < self.ny)
        result: IntArray = np.where(inside, j * self.nx + i, -1)
        return result


@dataclass(frozen=True, slots=True)
class Blocks:
    """One value per cell that holds soundings: where (the median position), the median
    depth, and how many soundings it reduces."""

    x: FloatArray
    y: FloatArray
    depth: FloatArray
    count: IntArray
    cell: IntArray  # the cell's number in its GridSpec
    noise_m: FloatArray  # the median's own standard error, from the cell's spread

    def __len__(self) -> int:
        return len(self.depth)

    def take(self, which: npt.NDArray[np.bool_]) -> Blocks:
        return Blocks(
            self.x[which],
            self.y[which],
            self.depth[which],
            self.count[which],
            self.cell[which],
            self.noise_m[which],
        )


def _group_median(cell: IntArray, values: FloatArray) -> FloatArray:
    """The median of `values` in each run of equal `cell` (cells ascending)."""
    order = np.lexsort((values, cell))
    ordered = values[order]
    starts = np.flatnonzero(np.concatenate([[True], np.diff(cell[order]) != 0]))
    sizes = np.diff(np.concatenate([starts, [len(values)]]))
    low = ordered[starts + (sizes - 1) // 2]
    high = ordered[starts + sizes // 2]
    result: FloatArray = (low + high) / 2.0
    return result


def block_median(x: FloatArray, y: FloatArray, depth: FloatArray, spec: GridSpec) -> Blocks:
    """The median depth and position of the soundings in each cell of `spec` that has any
    (points outside the grid are left out), cells in ascending order."""
    cell = spec.index(x, y)
    inside = cell >= 0
    cell, x, y, depth = cell[inside], x[inside], y[inside], depth[inside]
    if len(cell) == 0:
        empty = np.zeros(0)
        none = np.zeros(0, dtype=np.int64)
        return Blocks(empty, empty, empty, none, none, empty)
    cells, which, count = np.unique(cell, return_inverse=True, return_counts=True)
    median = _group_median(cell, depth)
    # A median's standard error: sqrt(pi / 2) sigma / sqrt(n), sigma from the cell's MAD.
    sigma = MAD_SCALE * _group_median(cell, np.abs(depth - median[which.ravel()]))
    return Blocks(
        _group_median(cell, x),
        _group_median(cell, y),
        median,
        count.astype(np.int64),
        cells.astype(np.int64),
        sigma * np.sqrt(np.pi / 2.0 / count),
    )
