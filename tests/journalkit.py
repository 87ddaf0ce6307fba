"""Test kit for the journal: a database that is "full" for as long as a test says.

"Full" is SQLite's own SQLITE_FULL ("database or disk is full"): while the
switch is on, every new connection caps the file at its current page count,
so it cannot grow by a single page. Turned off, the next reconnect sets no cap.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from cc_daemon.store import Journal


class DiskFull:
    """An `on_connect` hook for `Journal`; `full = False` makes room again."""

    def __init__(self) -> None:
        self.full = True

    def __call__(self, conn: sqlite3.Connection) -> None:
        if self.full:
            pages = conn.execute("PRAGMA page_count").fetchone()[0]
            conn.execute(f"PRAGMA max_page_count = {pages}").fetchone()


def full_journal(db: Path) -> tuple[Journal, DiskFull]:
    """A journal on an existing, empty file it cannot grow (until `full` is off)."""
    setup = Journal(db)
    setup.open()
    setup.close()
    disk = DiskFull()
    return Journal(db, on_connect=disk), disk
