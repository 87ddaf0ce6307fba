"""The way down and the way up of a cast, and the readings each keeps (the loop edit).

- **split**: by the winch's motion (its line out, else the probe's depth): the way
  down runs from the first reading to the first at the deepest line out, the way
  up from the last at the deepest line out to the end; the bottom dwell between
  belongs to neither;
- **loop edit**, on each way: the surface soak is dropped (every reading up to the
  soak's last: the probe was lowered to the soak depth and held there while its
  sensors settled, and the daemon labels those readings `soaking`); so is every
  reading taken while the probe stood still or moved against its way (the
  winch's speed under a quarter of the way's typical speed), and every reading of
  water already sampled on that way (not deeper than the deepest kept so far, on
  the way down). A stepped cast stands still at each level on
  purpose: there only the turning back and the water sampled twice are dropped,
  within the depth sensor's noise.

Pure: arrays in (in time order), indices out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

# Line out this close to the deepest is "at the bottom" (a count may wobble a little).
BOTTOM_TOLERANCE_M = 0.02
# Under this share of the way's typical speed, the probe is standing still.
STANDING_FRACTION = 0.25
# A stepped cast's readings at one level differ by the depth sensor's noise.
LEVEL_TOLERANCE_M = 0.05


@dataclass(frozen=True, slots=True)
class Ways:
    """Indices of the readings on the way down and on the way up, in time order."""

    down: IntArray
    up: IntArray


def motion(line_out_m: npt.ArrayLike, depth_m: npt.ArrayLike) -> FloatArray:
    """What the split and the speed read: the winch's line out, the probe's depth
    where the line out is missing."""
    line = np.asarray(line_out_m, dtype=np.float64)
    depth = np.asarray(depth_m, dtype=np.float64)
    found: FloatArray = np.where(np.isfinite(line), line, depth)
    return found


def split(time_s: npt.ArrayLike, moved: FloatArray) -> Ways:
    """The way down and the way up of a cast whose motion (`motion`) is `moved`."""
    t = np.asarray(time_s, dtype=np.float64)
    if len(t) != len(moved):
        raise ValueError("times and motion must have the same length")
    valid = np.flatnonzero(np.isfinite(moved))
    if len(valid) == 0:
        empty = np.array([], dtype=np.intp)
        return Ways(empty, empty)
    deepest = float(np.max(moved[valid]))
    bottom = valid[moved[valid] >= deepest - BOTTOM_TOLERANCE_M]
    return Ways(valid[valid <= bottom[0]], valid[valid >= bottom[-1]])


def speed(time_s: npt.ArrayLike, moved: FloatArray) -> FloatArray:
    """The motion's speed (m/s, positive down) at each reading: centred differences,
    one-sided at the ends; NaN where it cannot be told."""
    t = np.asarray(time_s, dtype=np.float64)
    found: FloatArray = np.full(len(t), np.nan)
    if len(t) < 2:
        return found
    with np.errstate(divide="ignore", invalid="ignore"):
        found[1:-1] = (moved[2:] - moved[:-2]) / (t[2:] - t[:-2])
        found[0] = (moved[1] - moved[0]) / (t[1] - t[0])
        found[-1] = (moved[-1] - moved[-2]) / (t[-1] - t[-2])
    return found


def loop_edit(
    way: IntArray,
    depth_m: npt.ArrayLike,
    speeds: FloatArray,
    *,
    down: bool = True,
    stepped: bool = False,
    soaking: npt.ArrayLike | None = None,
) -> IntArray:
    """The readings of `way` a profile keeps (see the module's docstring). `depth_m` is
    the probe's depth, `speeds` the motion's speed (`speed`) and `soaking` whether the
    reading belongs to the soak, each of the whole cast."""
    z = np.asarray(depth_m, dtype=np.float64)
    if soaking is not None and down:
        soak = np.flatnonzero(np.asarray(soaking, dtype=bool)[way])
        if len(soak):
            way = way[soak[-1] + 1 :]
    way = way[np.isfinite(z[way])]
    sign = 1.0 if down else -1.0
    forward = sign * speeds[way]
    moving = forward[np.isfinite(forward) & (forward > 0)]
    least = STANDING_FRACTION * float(np.median(moving)) if len(moving) else np.inf
    kept: list[int] = []
    reached = -np.inf
    for index, position, pace in zip(way, sign * z[way], forward, strict=True):
        if stepped:
            if position < reached - LEVEL_TOLERANCE_M or not pace > -least:
                continue
        elif not (pace >= least and position > reached):
            continue
        kept.append(int(index))
        reached = max(reached, float(position))
    return np.array(kept, dtype=np.intp)
