"""The density of fresh water from its temperature.

Martin & McCutcheon (1999), the equation rLakeAnalyzer's `water.density` uses for
salinity under 0.5 (fresh water: the sonde's lakes and reservoirs). Pure.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def water_density(temperature_c: npt.ArrayLike) -> FloatArray:
    """Density (kg/m³) of fresh water at `temperature_c` (°C); NaN stays NaN.

    >>> round(float(water_density(20.0)), 2)
    998.23
    """
    t = np.asarray(temperature_c, dtype=np.float64)
    rho: FloatArray = 1000.0 * (
        1.0 - (t + 288.9414) * (t - 3.9863) ** 2 / (508929.2 * (t + 68.12963))
    )
    return rho
