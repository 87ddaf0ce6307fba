"""The daemon's own sonar readings read back from the journal (`sonar_readings`).

This module owns the query that gives the readings back as `SonarReadingRecord`s,
each with its validity by the one rule the planner applies
(`core.cast.bottom.sounding_valid`): a reading is stored as it arrived and
flagged here, never mended. A journal from before the table existed has no
readings (not an error). It never writes.
"""

import sqlite3
from typing import NamedTuple

from cc_daemon.core.cast.bottom import sounding_valid


class SonarReadingRecord(NamedTuple):
    mono_s: float
    wall_s: float
    clock_synced: bool
    port: str
    distance_mm: int
    confidence_pct: int

    @property
    def valid(self) -> bool:
        return sounding_valid(self.distance_mm, self.confidence_pct)


def read_readings(
    conn: sqlite3.Connection, *, since: float | None = None, until: float | None = None
) -> list[SonarReadingRecord]:
    """The readings in time order, from `since` to `until` (wall clock), if given."""
    present = conn.execute(
        "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'sonar_readings'"
    ).fetchone()
    if present is None:
        return []
    rows = conn.execute(
        "SELECT mono_s, wall_s, clock_synced, port, distance_mm, confidence_pct"
        " FROM sonar_readings WHERE wall_s >= ? AND wall_s <= ? ORDER BY wall_s, id",
        (-1e300 if since is None else since, 1e300 if until is None else until),
    ).fetchall()
    return [SonarReadingRecord(r[0], r[1], bool(r[2]), r[3], int(r[4]), int(r[5])) for r in rows]
