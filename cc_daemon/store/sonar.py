"""The daemon's own sonar readings read back from the journal (`sonar_readings`).

This module owns the query that gives the readings back as `SonarReadingRecord`s,
each with its validity by the one rule the planner applies
(`core.cast.bottom.sounding_valid`): a reading is stored as it arrived and
flagged here, never mended. A journal from before the table existed has no
readings (not an error). It never writes, and never runs a query itself
(`store.reader` does, within its bounds).
"""

from typing import Any, NamedTuple

from cc_daemon.core.cast.bottom import sounding_valid
from cc_daemon.store.values import integer, number, text, wall_time


class SonarReadingRecord(NamedTuple):
    mono_s: float
    wall_s: float
    clock_synced: bool
    port: str
    distance_mm: int
    confidence_pct: int
    session_id: int | None = None  # the daemon run that journaled it

    @property
    def valid(self) -> bool:
        return sounding_valid(self.distance_mm, self.confidence_pct)


def query(
    *, since: float | None = None, until: float | None = None, session: int | None = None
) -> tuple[str, list[object]]:
    """The SELECT of the readings in time order, from `since` to `until` (wall clock),
    if given, of one `session` if given, and its parameters; each row becomes a record
    with `record`."""
    where = " AND session_id = ?" if session is not None else ""
    params: list[object] = [-1e300 if since is None else since, 1e300 if until is None else until]
    return (
        "SELECT mono_s, wall_s, clock_synced, port, distance_mm, confidence_pct, session_id"
        f" FROM sonar_readings WHERE wall_s >= ? AND wall_s <= ?{where} ORDER BY wall_s, id",
        params if session is None else [*params, session],
    )


def record(r: tuple[Any, ...]) -> SonarReadingRecord:
    """One stored reading; ValueError if its time or numbers cannot be read as such."""
    return SonarReadingRecord(
        number(r[0], "mono_s"),
        wall_time(r[1], "wall_s"),
        bool(r[2]),
        text(r[3], "port"),
        integer(r[4], "distance_mm"),
        integer(r[5], "confidence_pct"),
        None if r[6] is None else integer(r[6], "session_id"),
    )
