"""The hypsographic table as CSV: `depth_m,area_m2,volume_m3`, one row per depth.

This module owns the table's columns: exactly that header on the first line (what
the profiles' Schmidt stability reads; no comment line before it), depths to the
millimetre, areas in square metres and volumes in cubic metres to a tenth. It
writes through the project's CSV writer (`export.csv.writer`). Which survey it
is, its covered fraction and whether it is simulated are in the map's summary
beside it. It never reads the journal.
"""

from __future__ import annotations

from typing import TextIO

from cc_daemon.export.csv import writer
from cc_daemon.science.hypsography import Hypsography

HEADER = ("depth_m", "area_m2", "volume_m3")


def write(hypsography: Hypsography, out: TextIO) -> int:
    """Write the table to `out`; return its rows."""
    rows = writer(out)
    rows.writerow(HEADER)
    for depth, area, volume in hypsography.rows():
        rows.writerow([f"{depth:.3f}", f"{area:.1f}", f"{volume:.1f}"])
    return len(hypsography.depth_m)
