"""A survey's track for a map on a screen: its extent from every fix, its line from a
few thousand of them.

A ten-day survey holds 864,000 fixes; a phone's map needs a few thousand points
and the survey's extent (its south-west corner and mean latitude: the frame
`cc-daemon plot --survey` draws in). Both come from the fixes' session index in
SQL: the extent from aggregates over every fix, the line from every k-th fix,
the first and the last included, so memory holds the points drawn and no more.

It runs its queries through the reader it is given (`JournalReader.rows`) and
never opens or writes a file itself.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from cc_daemon.store.stationrows import Rows

MAX_POINTS = 2000


class Extent(NamedTuple):
    """What a frame needs of the fixes: their corner, and their latitudes' sum and count
    (to be averaged with other positions, as `LocalFrame.around` averages them)."""

    min_lat: float
    min_lon: float
    lat_sum: float
    fixes: int


class Track(NamedTuple):
    points: list[tuple[float, float]]  # (lat, lon), in the order sailed
    extent: Extent | None  # None: no fix


def track(reader: Rows, survey: int, max_points: int = MAX_POINTS) -> Track:
    """Survey `survey`'s track: at most about `max_points` fixes, and the extent of all."""
    (row,) = reader.rows(
        "SELECT count(*), min(lat_e7), min(lon_e7), sum(lat_e7), min(id), max(id)"
        " FROM fixes WHERE session_id = ?",
        "fixes",
        (survey,),
    )
    count, min_lat, min_lon, lat_sum, first, last = row
    if not count or not all(isinstance(v, int) for v in (min_lat, min_lon, first, last)):
        return Track([], None)
    stride = max(1, math.ceil(count / max_points))
    rows = reader.rows(
        "SELECT lat_e7, lon_e7 FROM fixes WHERE session_id = ?"
        " AND (id % ? = 0 OR id = ? OR id = ?) ORDER BY session_id, mono_s, id",
        "fixes",
        (survey, stride, first, last),
    )
    points = [
        (lat / 1e7, lon / 1e7)
        for lat, lon in rows
        if isinstance(lat, int) and isinstance(lon, int) and abs(lat) <= 9e8 and abs(lon) <= 18e8
    ]
    return Track(points, Extent(min_lat / 1e7, min_lon / 1e7, float(lat_sum) / 1e7, count))
