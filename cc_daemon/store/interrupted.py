"""What a previous run left behind: casts with no end, and a session with no stop.

Read once at start, after `Journal.open()` has marked the crashed casts
`unfinished`: for each, the station's position and the last depth journaled;
and whether the session before this one recorded `daemon_stopped` (if not, the
daemon died: a kill, a crash, a power cut). Read-only, on its own connection;
it never changes the journal.
"""

from __future__ import annotations

import sqlite3
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True, slots=True)
class InterruptedCast:
    cast_id: int
    lon_e7: int
    lat_e7: int
    samples: int
    last_depth_m: float | None  # the last depth journaled, None without a sample


@dataclass(frozen=True, slots=True)
class DiedSession:
    session_id: int
    pid: int | None
    opened_wall_s: float | None


def interrupted_casts(path: Path, cast_ids: list[int]) -> list[InterruptedCast]:
    if not cast_ids:
        return []
    out: list[InterruptedCast] = []
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as conn:
        for cast_id in cast_ids:
            row = conn.execute(
                "SELECT lon_e7, lat_e7 FROM casts WHERE id = ?", (cast_id,)
            ).fetchone()
            if row is None:
                continue
            samples, last = conn.execute(
                "SELECT count(*), (SELECT depth_m FROM samples WHERE cast_id = ?1"
                " ORDER BY id DESC LIMIT 1) FROM samples WHERE cast_id = ?1",
                (cast_id,),
            ).fetchone()
            out.append(InterruptedCast(cast_id, row[0], row[1], samples, last))
    return out


def died_session(path: Path) -> DiedSession | None:
    """The session before the newest one, if it never recorded `daemon_stopped`."""
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as conn:
        rows = conn.execute(
            "SELECT id, pid, opened_wall_s FROM sessions ORDER BY id DESC LIMIT 2"
        ).fetchall()
        if len(rows) < 2:
            return None
        session_id, pid, opened = rows[1]
        stopped = conn.execute(
            "SELECT 1 FROM events WHERE session_id = ? AND kind = 'daemon_stopped'",
            (session_id,),
        ).fetchone()
    return None if stopped else DiedSession(session_id, pid, opened)
