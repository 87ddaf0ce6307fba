"""Quality control of soundings: which to keep, and why each other one was rejected.

Every rejection keeps its reason (`Reason`), so a product can say how many went
for each. The rules, in the order they are applied (a sounding is rejected for
the first that holds):

1. `INVALID`: the reading cannot be true (flagged by the journal's read side: a
   confidence over 100 %, a distance of a kilometre or more);
2. `NO_ECHO`: a distance of 0 (a Ping1D's lost echo);
3. `LOW_CONFIDENCE`: a confidence under the threshold;
4. `POSITION_JUMP`: a fix whose position needs an impossible speed to reach and
   to leave (a GPS glitch), and every sounding placed by it;
5. `OFF_TRACK`: a reading that cannot be placed on the track (no fixes around it
   within the allowed gap; decided by the caller, who places readings);
6. `SPIKE`: a depth that stands out from its along-track neighbours by a robust
   rule: farther from the running median of `window` neighbours than `n_mad`
   times their scaled median absolute deviation, and than a floor that grows
   with the depth (an echosounder's stated accuracy is so many centimetres plus
   a fraction of the depth).

Pure: arrays in, arrays out (numpy).
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
import numpy.typing as npt

from cc_daemon.science.bathymetry.blocks import MAD_SCALE

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]


class Reason(IntEnum):
    """Why a sounding was not used (KEPT: it was)."""

    KEPT = 0
    INVALID = 1
    NO_ECHO = 2
    LOW_CONFIDENCE = 3
    POSITION_JUMP = 4
    OFF_TRACK = 5
    SPIKE = 6

    @property
    def label(self) -> str:
        return self.name.lower()


def screen(
    distance_m: FloatArray,
    confidence_pct: FloatArray,
    valid: BoolArray,
    *,
    min_confidence_pct: float,
) -> npt.NDArray[np.int8]:
    """Rules 1 to 3 on each reading: its `Reason` (KEPT where none holds)."""
    reasons = np.zeros(len(distance_m), dtype=np.int8)
    low = confidence_pct < min_confidence_pct
    reasons[low] = Reason.LOW_CONFIDENCE
    reasons[distance_m <= 0.0] = Reason.NO_ECHO
    reasons[~valid] = Reason.INVALID
    return reasons


def position_jumps(
    t_s: FloatArray, x_m: FloatArray, y_m: FloatArray, segment: IntArray, *, max_speed_m_s: float
) -> BoolArray:
    """Fixes (in time order) that a GPS glitch threw off the track: reaching them from the
    fix before and leaving them for the fix after both need more than `max_speed_m_s`,
    while the fixes either side are within reach of each other (a real move is kept).
    A segment's first or last fix is judged on its one neighbour."""
    n = len(t_s)
    jumped = np.zeros(n, dtype=bool)
    if n < 2:
        return jumped

    def speed(a: slice, b: slice) -> FloatArray:
        dt = np.maximum(np.abs(t_s[b] - t_s[a]), 1e-3)
        result: FloatArray = np.hypot(x_m[b] - x_m[a], y_m[b] - y_m[a]) / dt
        return result

    same = segment[1:] == segment[:-1]
    step = speed(slice(0, -1), slice(1, None))  # fix i -> i + 1
    too_fast = (step > max_speed_m_s) & same
    into = np.concatenate([[False], too_fast])  # reaching fix i was too fast
    out_of = np.concatenate([too_fast, [False]])  # leaving fix i was too fast
    has_before = np.concatenate([[False], same])
    has_after = np.concatenate([same, [False]])
    jumped = into & out_of
    if n >= 3:
        across = speed(slice(0, -2), slice(2, None)) <= max_speed_m_s
        jumped[1:-1] &= across
    # The ends of a segment have one neighbour: a leap to or from it is the glitch.
    jumped |= into & ~has_after
    jumped |= out_of & ~has_before
    result: BoolArray = np.asarray(jumped, dtype=bool)
    return result


def spikes(
    depth_m: FloatArray,
    segment: IntArray,
    *,
    window: int = 15,
    n_mad: float = 4.0,
    floor_m: float = 0.10,
    floor_fraction: float = 0.03,
) -> BoolArray:
    """Rule 6 on soundings in along-track (time) order, each segment (one source, one pass
    without a gap) on its own: True where a depth is a spike. `window` (odd) neighbours
    around each sounding give the running median and MAD; at a segment's ends the window
    is what the segment has."""
    n = len(depth_m)
    if n == 0:
        return np.zeros(0, dtype=bool)
    half = window // 2
    padded, where = _padded(depth_m, segment, half)
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)[where]
    median = np.nanmedian(windows, axis=1)
    mad = np.nanmedian(np.abs(windows - median[:, None]), axis=1)
    limit = np.maximum(n_mad * MAD_SCALE * mad, floor_m + floor_fraction * np.abs(median))
    result: BoolArray = np.abs(depth_m - median) > limit
    return result


def _padded(values: FloatArray, segment: IntArray, half: int) -> tuple[FloatArray, IntArray]:
    """`values` with `half` NaNs before each segment and after the last, and where each
    value's window starts in it: no window reaches into another segment."""
    starts = np.flatnonzero(np.concatenate([[True], segment[1:] != segment[:-1]]))
    # Each value moves right by `half` NaNs for every segment start at or before it.
    shift = np.searchsorted(starts, np.arange(len(values)), side="right") * half
    padded = np.full(len(values) + half * (len(starts) + 1), np.nan)
    positions = np.arange(len(values)) + shift
    padded[positions] = values
    return padded, positions - half


def counts(reasons: npt.NDArray[np.int8]) -> dict[str, int]:
    """How many soundings went for each reason (and were kept), every reason named."""
    found = np.bincount(reasons.astype(np.int64), minlength=len(Reason))
    return {reason.label: int(found[reason]) for reason in Reason}
