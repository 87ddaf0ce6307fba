"""The sonde's readings in the journal: their table, their rows and reading them back.

This module owns the `sonde_samples` table (the migration that adds it, written
as one self-contained step so it can take any place in `schema.MIGRATIONS`),
the row `Journal.record_sonde_sample` hands the writer, the INSERT that stores
it, and the query and the conversion that give the readings back as
`SondeSampleRecord`s.

A reading is stored whole: the request's monotonic and wall-clock times, the
cast and phase it belongs to (NULL and "surface" between casts), the winch's
line out when the request went out, the sonde's own depth, the status of the
request and every parameter's value in `values_json` (JSON null when missing)
with the reason of each missing one in `missing_json`. A missing value is never
written as a number, and a stored one that is not a finite number is never read
back as one (`record` refuses the row). It never imports asyncio or the sonde's
reader, and never runs a query itself (`store.reader` does, within its bounds).
"""

import json
import math
from collections.abc import Mapping
from typing import Any, NamedTuple

from cc_daemon.store.values import integer, json_value, number, text, wall_time

# Row kind in the journal's buffer (0 to 4 are journal.py's).
SONDE = 5

MIGRATION: tuple[str, ...] = (
    """CREATE TABLE sonde_samples (
        id INTEGER PRIMARY KEY,
        session_id INTEGER REFERENCES sessions(id),
        cast_id INTEGER REFERENCES casts(id),
        phase TEXT NOT NULL,
        mono_s REAL NOT NULL,
        wall_s REAL NOT NULL,
        clock_synced INTEGER NOT NULL,
        duration_s REAL NOT NULL,
        status TEXT NOT NULL,
        error TEXT,
        line_out_m REAL,
        sonde_depth_m REAL,
        simulated INTEGER NOT NULL,
        values_json TEXT NOT NULL,
        missing_json TEXT NOT NULL
    )""",
    "CREATE INDEX sonde_samples_by_cast ON sonde_samples(cast_id, mono_s)",
    "CREATE INDEX sonde_samples_by_wall ON sonde_samples(wall_s)",
)

COLUMNS: tuple[str, ...] = (
    "cast_id",
    "phase",
    "mono_s",
    "wall_s",
    "clock_synced",
    "duration_s",
    "status",
    "error",
    "line_out_m",
    "sonde_depth_m",
    "simulated",
    "values_json",
    "missing_json",
)
INSERT = (
    f"INSERT INTO sonde_samples (session_id, {', '.join(COLUMNS)})"
    f" VALUES ({', '.join('?' * (len(COLUMNS) + 1))})"
)


class SondeSampleRecord(NamedTuple):
    cast_id: int | None
    phase: str
    mono_s: float
    wall_s: float
    clock_synced: bool
    duration_s: float
    status: str
    error: str | None
    line_out_m: float | None
    sonde_depth_m: float | None
    simulated: bool
    values: dict[str, float | None]
    missing: dict[str, str]


def build_row(
    *,
    cast_id: int | None,
    phase: str,
    mono_s: float,
    wall_s: float,
    clock_synced: int,
    duration_s: float,
    status: str,
    error: str | None,
    line_out_m: float | None,
    sonde_depth_m: float | None,
    simulated: bool,
    values: Mapping[str, float | None],
    missing: Mapping[str, str],
) -> tuple[Any, ...]:
    """The buffer row: the kind, then the INSERT's values after `session_id`."""
    clean = {
        k: (float(v) if v is not None and math.isfinite(v) else None) for k, v in values.items()
    }
    return (
        SONDE,
        cast_id,
        phase,
        mono_s,
        wall_s,
        clock_synced,
        duration_s,
        status,
        error,
        line_out_m,
        sonde_depth_m,
        1 if simulated else 0,
        json.dumps(clean, separators=(",", ":")),
        json.dumps(dict(missing), separators=(",", ":"), sort_keys=True),
    )


def query(
    *, cast_id: int | None = None, since: float | None = None, session: int | None = None
) -> tuple[str, list[object]]:
    """The SELECT of the readings in time order (of one session, if given), and its
    parameters; each row becomes a record with `record`."""
    clauses: list[str] = []
    params: list[object] = []
    if cast_id is not None:
        clauses.append("cast_id = ?")
        params.append(cast_id)
    if since is not None:
        clauses.append("wall_s >= ?")
        params.append(since)
    if session is not None:
        clauses.append("session_id = ?")
        params.append(session)
    where = f" WHERE {' AND '.join(clauses)}" if clauses else ""
    return f"SELECT {', '.join(COLUMNS)} FROM sonde_samples{where} ORDER BY mono_s, id", params


def _values(raw: Any) -> dict[str, float | None]:
    found = json_value(raw)
    if not isinstance(found, dict):
        raise ValueError("the values are not a JSON object")
    return {
        str(name): None if value is None else number(value, f"value {name!r}")
        for name, value in found.items()
    }


def _missing(raw: Any) -> dict[str, str]:
    found = json_value(raw)
    if not isinstance(found, dict) or not all(isinstance(v, str) for v in found.values()):
        raise ValueError("the missing values' reasons are not a JSON object of text")
    return {str(name): reason for name, reason in found.items()}


def record(r: tuple[Any, ...]) -> SondeSampleRecord:
    """One stored reading; ValueError if a value in it cannot be true (the reader skips it)."""
    return SondeSampleRecord(
        cast_id=None if r[0] is None else integer(r[0], "a reading's cast"),
        phase=text(r[1], "phase"),
        mono_s=number(r[2], "mono_s"),
        wall_s=wall_time(r[3], "wall_s"),
        clock_synced=bool(r[4]),
        duration_s=number(r[5], "duration_s"),
        status=text(r[6], "status"),
        error=None if r[7] is None else text(r[7], "error"),
        line_out_m=None if r[8] is None else number(r[8], "line_out_m"),
        sonde_depth_m=None if r[9] is None else number(r[9], "sonde_depth_m"),
        simulated=bool(r[10]),
        values=_values(r[11]),
        missing=_missing(r[12]),
    )
