"""A run's session in the journal: its row, and the casts a crash left open.

Each run of the daemon opens one session (its survey, `store.surveys`): the
boot it ran in, its pid and software, when it opened, and which winch its data
come from. The first time a run opens a file it closes the casts a previous
run left without an end (a crash, a kill, a power cut). Called on the
journal's writer thread, with its connection; nothing else.
"""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

from cc_daemon import __version__
from cc_daemon.store.rows import RECOVER_UNFINISHED

BOOT_ID = Path("/proc/sys/kernel/random/boot_id")


def boot_id() -> str | None:
    try:
        return BOOT_ID.read_text().strip()
    except OSError:
        return None


def session_exists(conn: sqlite3.Connection, session_id: int) -> bool:
    found = conn.execute("SELECT 1 FROM sessions WHERE id = ?", (session_id,)).fetchone()
    return found is not None


def open_session(
    conn: sqlite3.Connection,
    *,
    monotonic: float,
    wall: float,
    clock_synced: int,
    winch_backend: str | None,
    simulated: int | None,
) -> int | None:
    """A new session row for this run; its id."""
    cursor = conn.execute(
        "INSERT INTO sessions (boot_id, pid, software, opened_mono_s, opened_wall_s,"
        " clock_synced, winch_backend, simulated) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
        (
            boot_id(),
            os.getpid(),
            f"cc-daemon {__version__}",
            monotonic,
            wall,
            clock_synced,
            winch_backend,
            simulated,
        ),
    )
    return cursor.lastrowid


def close_unfinished(conn: sqlite3.Connection, reason: str) -> list[tuple[int, int, float | None]]:
    """Mark every cast without an end `unfinished`; each one's id, samples, deepest."""
    found = conn.execute(
        "SELECT c.id, count(s.id), max(s.depth_m) FROM casts c"
        " LEFT JOIN samples s ON s.cast_id = c.id"
        " WHERE c.outcome IS NULL GROUP BY c.id ORDER BY c.id"
    ).fetchall()
    if found:
        conn.execute(RECOVER_UNFINISHED, (reason,))
    return [(int(i), int(n), deepest) for i, n, deepest in found]
