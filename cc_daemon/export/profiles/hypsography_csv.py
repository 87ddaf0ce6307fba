"""A lake's hypsography from its CSV: `depth_m,area_m2,volume_m3`, as `cc-daemon map` writes it.

This module owns reading that table into a `science.hypsography.Hypsography` for
Schmidt stability: one header line naming the three columns (in any order; other
columns ignored, `#` comment lines skipped), then one row per depth, increasing
from 0 (the surface). A file that cannot be that raises `ValueError` with one
line saying where and why; nothing is guessed or mended. A `covered_fraction`
column, when present (one value), says how much of the lake the bed was mapped
for. It reads only the file it is given.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from cc_daemon.science.hypsography import Hypsography

COLUMNS = ("depth_m", "area_m2", "volume_m3")
MAX_ROWS = 100_000  # a hypsography a metre apart to 100 km deep is a tenth of this


def read_hypsography(path: Path) -> Hypsography:
    """The hypsography in `path`; ValueError naming the file, the line and the problem."""
    with path.open(encoding="utf-8", newline="") as f:
        lines = (line for line in f if not line.lstrip().startswith("#"))
        rows = csv.DictReader(lines)
        missing = [c for c in COLUMNS if c not in (rows.fieldnames or ())]
        if missing:
            raise ValueError(
                f"{path}: no column {', '.join(missing)} (header: depth_m,area_m2,volume_m3)"
            )
        values: dict[str, list[float]] = {c: [] for c in COLUMNS}
        covered: set[float] = set()
        for number, row in enumerate(rows, start=2):
            if number > MAX_ROWS:
                raise ValueError(f"{path}: more than {MAX_ROWS} rows")
            for c in COLUMNS:
                try:
                    value = float(row[c] or "")
                except ValueError:
                    raise ValueError(
                        f"{path}: row {number}: {c} {row[c]!r} is not a number"
                    ) from None
                if not math.isfinite(value):
                    raise ValueError(f"{path}: row {number}: {c} {row[c]!r} is not a number")
                values[c].append(value)
            if row.get("covered_fraction"):
                try:
                    covered.add(float(row["covered_fraction"]))
                except ValueError:
                    raise ValueError(
                        f"{path}: row {number}: covered_fraction is not a number"
                    ) from None
    try:
        return Hypsography(
            depth_m=np.array(values["depth_m"]),
            area_m2=np.array(values["area_m2"]),
            volume_m3=np.array(values["volume_m3"]),
            covered_fraction=covered.pop() if len(covered) == 1 else 1.0,
        )
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
