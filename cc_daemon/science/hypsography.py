"""A lake's hypsography: the area of each depth's plane and the volume below it.

The value the bathymetry hands to the profiles (Schmidt stability, heat budgets):
made from a gridded bed, read as rLakeAnalyzer reads `bthA` and `bthD`. Depths are
metres below the water surface of the survey's day, increasing; areas in m² of the
horizontal plane at each depth (the lake's surface area at depth 0); volumes in m³
of water below each depth's plane. It never reads a grid or a file itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Hypsography:
    """Area (m²) and volume below (m³) at increasing depths (m); `area_m2[0]` is the
    surface's. `covered_fraction` says how much of the water the bed under it was
    mapped for (1.0: all of it), so a reader can tell a partial survey's curve."""

    depth_m: FloatArray
    area_m2: FloatArray
    volume_m3: FloatArray
    covered_fraction: float = 1.0

    def __post_init__(self) -> None:
        n = len(self.depth_m)
        if n < 2 or len(self.area_m2) != n or len(self.volume_m3) != n:
            raise ValueError("a hypsography needs two depths or more, an area and a volume each")
        if not np.all(np.diff(self.depth_m) > 0) or self.depth_m[0] != 0.0:
            raise ValueError("depths must start at 0 (the surface) and increase")
        if np.any(self.area_m2 < 0) or np.any(np.diff(self.area_m2) > 0):
            raise ValueError("areas must be >= 0 and never grow with depth")
        if not 0.0 < self.covered_fraction <= 1.0:
            raise ValueError("covered_fraction must be in (0, 1]")

    @classmethod
    def from_depths(
        cls,
        depth_m: FloatArray,
        cell_area_m2: float,
        interval_m: float,
        covered_fraction: float = 1.0,
    ) -> Hypsography:
        """The hypsography of a gridded bed: `depth_m` one depth per cell of `cell_area_m2`
        (NaN: a cell not mapped, left out), at 0, `interval_m`, 2 `interval_m`, ... down
        to the first depth at or below the deepest cell (where the area is 0). The area at
        each depth is the cells deeper than it (at 0: every mapped cell); the volume below
        it, the water between its plane and the bed, cell by cell."""
        if interval_m <= 0 or cell_area_m2 <= 0:
            raise ValueError("the interval and the cell's area must be > 0")
        bed = np.asarray(depth_m, dtype=np.float64)
        bed = np.clip(bed[np.isfinite(bed)], 0.0, None)
        deepest = float(bed.max()) if len(bed) else 0.0
        steps = max(int(np.ceil(deepest / interval_m - 1e-9)), 1)
        depths = np.arange(steps + 1) * interval_m
        ordered = np.sort(bed)
        below = len(ordered) - np.searchsorted(ordered, depths, side="right")  # deeper than z
        area = below * cell_area_m2
        area[0] = len(ordered) * cell_area_m2
        # Sum over cells deeper than z of (d - z): suffix sums of the sorted depths.
        suffix = np.concatenate([np.cumsum(ordered[::-1])[::-1], [0.0]])
        first = len(ordered) - below
        volume = (suffix[first] - below * depths) * cell_area_m2
        return cls(
            depths.astype(np.float64),
            area.astype(np.float64),
            volume.astype(np.float64),
            covered_fraction,
        )

    def rows(self) -> list[tuple[float, float, float]]:
        """(depth m, area m², volume m³) per depth, as the CSV `depth_m,area_m2,volume_m3`."""
        return [
            (float(d), float(a), float(v))
            for d, a, v in zip(self.depth_m, self.area_m2, self.volume_m3, strict=True)
        ]
