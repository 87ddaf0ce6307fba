"""The whole map from the soundings kept: spacing, grid, cross-validation, hypsography.

One call that does what `cc-daemon map` does between reading the journal and
writing the products, with every choice it made said in the result: the line
spacing it found in the track (or that it found none, and used
`FALLBACK_SPACING_M`'s rules), the cell size and maximum distance (given, or by
the rules of `spacing`), the interpolator, the cross-validation and the
hypsography. Pure: arrays in, a `BedMap` out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from cc_daemon.science.bathymetry import interpolate, spacing
from cc_daemon.science.bathymetry.blocks import Blocks, GridSpec
from cc_daemon.science.bathymetry.grid import Grid, make_grid, max_edge_m
from cc_daemon.science.bathymetry.validation import CrossValidation, block_kfold
from cc_daemon.science.hypsography import Hypsography

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

FALLBACK_SPACING_M = 20.0  # the rules used when the track shows no parallel lines
MIN_SOUNDINGS = 10


@dataclass(frozen=True, slots=True)
class BedMap:
    grid: Grid
    blocks: Blocks
    cv: CrossValidation
    hypsography: Hypsography | None  # None: no cell mapped
    spacing_m: float | None  # found in the track; None: no second pass
    rules_spacing_m: float  # the spacing the rules were applied to
    cell_m: float
    max_distance_m: float
    method: str


def map_bed(
    x: FloatArray,
    y: FloatArray,
    depth: FloatArray,
    *,
    track_x: FloatArray,
    track_y: FloatArray,
    track_segment: IntArray,
    cell_m: float | None = None,
    max_distance_m: float | None = None,
    method: str = interpolate.DEFAULT,
    hypsography_interval_m: float | None = None,
    folds: int = 5,
) -> BedMap:
    """Map the bed from the soundings kept (`x`, `y` projected metres, `depth` metres below
    the surface), the track (fixes kept, time order, with their pass) giving the spacing.
    ValueError when there are too few soundings, or they lie on one line."""
    if len(depth) < MIN_SOUNDINGS:
        raise ValueError(f"{len(depth)} soundings kept: at least {MIN_SOUNDINGS} make a map")
    found = spacing.line_spacing_m(track_x, track_y, track_segment)
    rules = found if found is not None else FALLBACK_SPACING_M
    cell = cell_m if cell_m is not None else spacing.cell_m(rules)
    reach = max_distance_m if max_distance_m is not None else spacing.max_distance_m(rules)
    spec = GridSpec.covering(x, y, cell)
    grid, blocks = make_grid(x, y, depth, spec, max_distance_m=reach, method=method)
    cv = block_kfold(
        blocks,
        block_m=spacing.cv_block_m(rules),
        folds=folds,
        method=method,
        max_edge_m=max_edge_m(reach),
    )
    hypsography = None
    if grid.mapped_cells:
        finite = grid.depth_m[grid.mapped]
        interval = hypsography_interval_m or default_interval_m(float(finite.max()))
        hypsography = Hypsography.from_depths(
            grid.depth_m, spec.cell_area_m2, interval, max(grid.covered_fraction, 1e-9)
        )
    return BedMap(grid, blocks, cv, hypsography, found, rules, cell, reach, method)


def default_interval_m(deepest_m: float) -> float:
    """The hypsography's interval: 0.5 m to 20 m of water, 1 m deeper, 0.1 m under 2 m."""
    if deepest_m <= 2.0:
        return 0.1
    return 0.5 if deepest_m <= 20.0 else 1.0
