"""One cast made into its two binned profiles: lag corrected, split, loop edited, binned.

The order matters once: the lag is corrected on the whole time series first (a
sensor's state runs on through the bottom dwell and the turn), then each way's
readings are chosen. Each kept reading's depth is then the line through the
way's depths around it (`local.local_line`, nine readings): the probe moves
smoothly on a winch, its pressure sensor does not read smoothly, and in a
thermocline 1 cm of depth is 0.04 °C. Then the binning. Pure: a `Series` in, a
`Processed` out.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from cc_daemon.science.profiles.binning import Binned, bin_average, bin_index
from cc_daemon.science.profiles.casts import loop_edit, motion, speed, split
from cc_daemon.science.profiles.lag import WINDOW, Method, correct_lag
from cc_daemon.science.profiles.local import local_line

# Readings either side of each in the line that gives its depth (nine in all).
DEPTH_WINDOW = 4

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class Series:
    """One cast's readings in time order: the time (s, one clock), the probe's depth
    (m, its pressure depth), the winch's line out (m, NaN where unknown), whether
    each belongs to the soak, and each parameter's values (NaN where missing)."""

    time_s: FloatArray
    depth_m: FloatArray
    line_out_m: FloatArray
    values: Mapping[str, FloatArray]
    soaking: BoolArray | None = None

    def __post_init__(self) -> None:
        n = len(self.time_s)
        lengths = [len(self.depth_m), len(self.line_out_m), *map(len, self.values.values())]
        if self.soaking is not None:
            lengths.append(len(self.soaking))
        if any(length != n for length in lengths):
            raise ValueError("every array of a series must be as long as its times")
        if n > 1 and np.any(np.diff(self.time_s) < 0):
            raise ValueError("a series must be in time order")


@dataclass(frozen=True, slots=True)
class Settings:
    """How to make profiles: bins, the least readings a bin should have, each
    parameter's response time (s; 0 or absent: not corrected), the correction."""

    bin_m: float = 0.25
    min_count: int = 2
    response_s: Mapping[str, float] = field(default_factory=dict)
    method: Method = "inverse"
    window: int = WINDOW
    stepped: bool = False


@dataclass(frozen=True, slots=True)
class Processed:
    """A cast's corrected values, the readings kept on each way with the depth given to
    each (in the same order), and its profiles."""

    corrected: Mapping[str, FloatArray]
    down_readings: IntArray
    up_readings: IntArray
    down_depth_m: FloatArray
    up_depth_m: FloatArray
    down: Binned
    up: Binned


def process(series: Series, settings: Settings, *, bins: range | None = None) -> Processed:
    """`series` made into profiles with `settings`; `bins` (bin numbers) puts every cast
    of a survey on one grid, else the cast's own depths give it."""
    corrected = {
        name: correct_lag(
            series.time_s,
            values,
            settings.response_s.get(name, 0.0),
            method=settings.method,
            window=settings.window,
        )
        for name, values in series.values.items()
    }
    moved = motion(series.line_out_m, series.depth_m)
    ways = split(series.time_s, moved)
    speeds = speed(series.time_s, moved)
    down = loop_edit(
        ways.down, series.depth_m, speeds, stepped=settings.stepped, soaking=series.soaking
    )
    up = loop_edit(ways.up, series.depth_m, speeds, down=False, stepped=settings.stepped)
    down_depth = local_line(series.time_s[down], series.depth_m[down], DEPTH_WINDOW)
    up_depth = local_line(series.time_s[up], series.depth_m[up], DEPTH_WINDOW)
    if bins is None:
        kept = bin_index(np.concatenate((down_depth, up_depth)), settings.bin_m)
        bins = range(int(kept.min()), int(kept.max()) + 1) if len(kept) else range(0)

    def binned(readings: IntArray, depth: FloatArray) -> Binned:
        return bin_average(
            depth,
            {name: values[readings] for name, values in corrected.items()},
            settings.bin_m,
            min_count=settings.min_count,
            bins=bins,
        )

    return Processed(
        corrected,
        down,
        up,
        down_depth,
        up_depth,
        binned(down, down_depth),
        binned(up, up_depth),
    )
