"""The sonde's readings in the journal: their table, their rows and reading them back.

This module owns the `sonde_samples` table (the migration that adds it, written
as one self-contained step so it can take any place in `schema.MIGRATIONS`),
the row `Journal.record_sonde_sample` hands the writer, the INSERT that stores
it, and the query that gives the readings back as `SondeSampleRecord`s.

A reading is stored whole: the request's monotonic and wall-clock times, the
cast and phase it belongs to (NULL and "surface" between casts), the winch's
line out when the request went out, the sonde's own depth, the status of the
request and every parameter's value in `values_json` (JSON null when missing)
with the reason of each missing one in `missing_json`. A missing value is never
written as a number. It never imports asyncio or the sonde's reader.
"""

import json
import math
import sqlite3
from collections.abc import Mapping
from typing import Any, NamedTuple

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


def read_samples(
    conn: sqlite3.Connection,
    *,
    cast_id: int | None = None,
    since: float | None = None,
    session: int | None = None,
) -> list[SondeSampleRecord]:
    """Readings in time order (of one session, if given); none if the file predates
    the table."""
    present = conn.execute(
        "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'sonde_samples'"
    ).fetchone()
    if not present:
        return []
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
    rows = conn.execute(
        f"SELECT {', '.join(COLUMNS)} FROM sonde_samples{where} ORDER BY mono_s, id", params
    )
    return [
        SondeSampleRecord(
            cast_id=r[0],
            phase=r[1],
            mono_s=r[2],
            wall_s=r[3],
            clock_synced=bool(r[4]),
            duration_s=r[5],
            status=r[6],
            error=r[7],
            line_out_m=r[8],
            sonde_depth_m=r[9],
            simulated=bool(r[10]),
            values=json.loads(r[11]),
            missing=json.loads(r[12]),
        )
        for r in rows
    ]
