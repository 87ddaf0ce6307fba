"""Bin averaging on depth: a profile's value in each bin, with its count and spread.

Bins are `bin_m` thick and centred on whole multiples of it (0, 0.25, 0.5 m...,
the surface bin reaching up to -bin_m/2), as CTD software centres them, so every
cast of a survey shares one grid. Each bin holds, per parameter, the count of
readings, their mean, their sample standard deviation (NaN under two readings)
and their mean depth; a bin with fewer than `min_count` readings is flagged `few`,
its values kept. An empty bin has a count of 0 and NaN values: never a zero.

A bin's readings are rarely centred on it (at 0.125 m/s two readings a second
fall anywhere in a 0.25 m bin), and in a thermocline of 4 °C/m a mean taken 3 cm
off the centre is 0.12 °C off. So each bin also gives its `value` at the centre:
the mean moved along the profile's local gradient (the means of the neighbouring
bins against their readings' mean depths) from the readings' mean depth to the
centre. The profiles and what is read from them use that value. Pure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, slots=True)
class Binned:
    """One profile on depth bins: per parameter, each bin's count, mean, standard
    deviation, the readings' mean depth, the value at the bin's centre, and whether it
    has too few readings."""

    depth_m: FloatArray  # the bins' centres, increasing
    count: Mapping[str, IntArray]
    mean: Mapping[str, FloatArray]
    std: Mapping[str, FloatArray]
    reading_depth_m: Mapping[str, FloatArray]
    value: Mapping[str, FloatArray]
    few: Mapping[str, BoolArray]

    def present(self, name: str) -> tuple[FloatArray, FloatArray]:
        """The centres and values of the bins that hold a value of `name`."""
        keep = self.count[name] > 0
        return self.depth_m[keep], self.value[name][keep]


def bin_index(depth_m: npt.ArrayLike, bin_m: float) -> IntArray:
    """Each depth's bin: the nearest whole multiple of `bin_m`."""
    if bin_m <= 0:
        raise ValueError("bin_m must be > 0")
    z = np.asarray(depth_m, dtype=np.float64)
    found: IntArray = np.floor(z / bin_m + 0.5).astype(np.intp)
    return found


def at_centres(centres: FloatArray, mean: FloatArray, depth: FloatArray) -> FloatArray:
    """Each bin's mean moved from its readings' mean depth to its centre, along the
    gradient of the means against those depths (bins without readings skipped)."""
    found = np.full(len(centres), math.nan)
    keep = np.isfinite(mean) & np.isfinite(depth)
    if np.count_nonzero(keep) < 2:
        found[keep] = mean[keep]
        return found
    gradient = np.gradient(mean[keep], depth[keep])
    found[keep] = mean[keep] + gradient * (centres[keep] - depth[keep])
    return found


def bin_average(
    depth_m: npt.ArrayLike,
    values: Mapping[str, npt.ArrayLike],
    bin_m: float,
    *,
    min_count: int = 2,
    bins: range | None = None,
) -> Binned:
    """Average `values` (each as long as `depth_m`; NaN missing) on bins of `bin_m`.
    `bins`: the bin numbers to give (bin k is centred at k * bin_m); by default every
    bin from the shallowest reading's to the deepest's."""
    z = np.asarray(depth_m, dtype=np.float64)
    finite = np.isfinite(z)
    index = np.where(finite, bin_index(np.where(finite, z, 0.0), bin_m), 0)
    if bins is None:
        bins = (
            range(int(index[finite].min()), int(index[finite].max()) + 1)
            if finite.any()
            else range(0)
        )
    slot = index - bins.start
    inside = finite & (slot >= 0) & (slot < len(bins))
    centres = np.arange(bins.start, bins.stop, dtype=np.float64) * bin_m
    count: dict[str, IntArray] = {}
    mean: dict[str, FloatArray] = {}
    std: dict[str, FloatArray] = {}
    depth: dict[str, FloatArray] = {}
    for name, raw in values.items():
        v = np.asarray(raw, dtype=np.float64)
        if v.shape != z.shape:
            raise ValueError(f"{name}: values and depths must have the same length")
        use = inside & np.isfinite(v)
        n = np.bincount(slot[use], minlength=len(bins)).astype(np.intp)
        with np.errstate(divide="ignore", invalid="ignore"):
            average = np.bincount(slot[use], weights=v[use], minlength=len(bins)) / n
            squares = np.bincount(
                slot[use], weights=(v[use] - average[slot[use]]) ** 2, minlength=len(bins)
            )
            deviation = np.sqrt(squares / (n - 1))
            where = np.bincount(slot[use], weights=z[use], minlength=len(bins)) / n
        count[name] = n
        mean[name] = np.where(n > 0, average, math.nan)
        std[name] = np.where(n > 1, deviation, math.nan)
        depth[name] = np.where(n > 0, where, math.nan)
    return Binned(
        depth_m=centres,
        count=count,
        mean=mean,
        std=std,
        reading_depth_m=depth,
        value={name: at_centres(centres, mean[name], depth[name]) for name in values},
        few={name: n < min_count for name, n in count.items()},
    )
