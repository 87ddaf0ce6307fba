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
