"""A survey's line spacing, read from its track, and the grid's rules that follow from it.

Parallel lines `S` apart are the survey's design, and they set how fine a map it
can make: a sounding every metre along a line, none for `S` across. The rules
(docs/maps.md gives the figures behind them):

- cell size `S / 4`, rounded to 1, 2, 2.5 or 5 times a power of ten (5 m at
  20 m spacing): several soundings of a line in each cell for the median, and
  cells fine enough that interpolating between two lines is what fills them;
- maximum distance `0.75 S` from the nearest sounding: every cell between two
  adjacent lines (at most `S / 2` from one) is mapped; a line missed, or the
  water beyond the outer lines, is left empty;
- cross-validation blocks of `S / 2`: a held-out block leaves a gap along its
  line as wide as the gaps the map fills between lines are half-wide, so the
  error found at held-out soundings is the error of the cells (within a factor
  of 1.5 of the true error on the simulator's bed: docs/maps.md), and a line's
  near neighbours never leak into it.

The spacing is found as the median distance from points of the track to the
nearest point of another pass (a point whose distance along the track is
several times its distance across), for spacings up to about 150 m. A track with
no second pass (one transit) has none. Pure: arrays in, numbers out.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

CELL_PER_SPACING = 0.25
MAX_DISTANCE_PER_SPACING = 0.75
CV_BLOCK_PER_SPACING = 0.5
_NICE = (1.0, 2.0, 2.5, 5.0, 10.0)
_ANOTHER_PASS = 3.0  # along the track at least this many times the distance across
_MIN_PAIRS = 10
_SEGMENT_GAP_M = 1e9  # between segments along the track: always "another pass"


def nice(value: float) -> float:
    """`value` rounded (in ratio) to 1, 2, 2.5 or 5 times a power of ten."""
    if value <= 0:
        raise ValueError(f"{value}: must be > 0")
    power = 10.0 ** math.floor(math.log10(value))
    return min((n * power for n in _NICE), key=lambda c: abs(math.log(c / value)))


def cell_m(spacing_m: float) -> float:
    return nice(spacing_m * CELL_PER_SPACING)


def max_distance_m(spacing_m: float) -> float:
    return spacing_m * MAX_DISTANCE_PER_SPACING


def cv_block_m(spacing_m: float) -> float:
    return spacing_m * CV_BLOCK_PER_SPACING


def along_track_m(x: FloatArray, y: FloatArray, segment: IntArray) -> FloatArray:
    """Each point's distance along the track from the first (time order), a segment's
    points far from every other segment's."""
    step = np.hypot(np.diff(x), np.diff(y))
    new = segment[1:] != segment[:-1]
    step[new] = _SEGMENT_GAP_M
    return np.concatenate([[0.0], np.cumsum(step)])


def line_spacing_m(x: FloatArray, y: FloatArray, segment: IntArray) -> float | None:
    """The spacing of the survey's lines, from the track (positions in time order, each
    pass's `segment`); None when the track has no second pass to measure it against."""
    if len(x) < 3:
        return None
    s = along_track_m(x, y, segment)
    # First a point every 5 m with 64 neighbours: a line's own points reach 160 m either
    # way, so the next line is among them for any spacing up to that; then finer.
    first = _spacing(x, y, s, step_m=5.0, k=64)
    if first is None:
        return None
    return _spacing(x, y, s, step_m=max(first / 4.0, 0.25), k=24) or first


def _spacing(x: FloatArray, y: FloatArray, s: FloatArray, *, step_m: float, k: int) -> float | None:
    from scipy.spatial import cKDTree

    bins = np.floor(s / step_m)
    keep = np.concatenate([[True], bins[1:] != bins[:-1]])
    px, py, ps = x[keep], y[keep], s[keep]
    if len(px) < 3:
        return None
    tree = cKDTree(np.column_stack([px, py]))
    distance, index = tree.query(np.column_stack([px, py]), k=min(k, len(px)))
    along = np.abs(ps[:, None] - ps[index])
    other = (along > _ANOTHER_PASS * distance) & (distance > 0)
    nearest = np.where(other, distance, np.inf).min(axis=1)
    found = nearest[np.isfinite(nearest)]
    if len(found) < _MIN_PAIRS:
        return None
    return float(np.median(found))
