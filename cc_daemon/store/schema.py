"""The journal's on-disk layout: every schema version and the migrations between them.

This module owns the SQL that shapes a journal file: the tables, the schema
version kept in `PRAGMA user_version`, the `PRAGMA application_id` that marks a
file as ours, and the ordered list of migrations that brings any older file up
to `SCHEMA_VERSION`. A fresh file is built by running every migration from
version 0, so a new file and a migrated old one have exactly the same layout.

It must never edit a migration that has shipped (files in the field were built
by it; add a new one instead), never migrate a file that is not a cc-daemon
journal, and never touch a file written by a newer cc-daemon.

Units, fixed across versions: times are seconds (`mono_s` from the monotonic
clock of the boot that wrote the row, `wall_s` Unix time UTC from the system
clock, `clock_synced` 1 when the kernel said the clock was synchronised:
`status.clocksync`);
positions are the autopilot's integers (degrees x 1e7, millimetres); depths
written by the daemon are metres.
"""

from __future__ import annotations

import sqlite3

from cc_daemon.core.errors import CcDaemonError
from cc_daemon.store import sonde

# "ccdj" in ASCII: lets us refuse to migrate some other program's SQLite file.
APPLICATION_ID = 0x6363646A

# Version 1, the first layout: fixes, casts, samples and events. REFERENCES
# documents the links; foreign keys stay unenforced (SQLite's default) so a
# sample whose cast row is missing is still kept rather than refused.
_V1: tuple[str, ...] = (
    """CREATE TABLE fixes (
        id INTEGER PRIMARY KEY,
        mono_s REAL NOT NULL,
        wall_s REAL NOT NULL,
        clock_synced INTEGER NOT NULL,
        frame TEXT NOT NULL,
        ap_timestamp_s INTEGER NOT NULL,
        lon_e7 INTEGER NOT NULL,
        lat_e7 INTEGER NOT NULL,
        alt_mm INTEGER NOT NULL,
        sonar_distance_mm INTEGER NOT NULL,
        sonar_confidence_pct INTEGER NOT NULL
    )""",
    """CREATE TABLE casts (
        id INTEGER PRIMARY KEY,
        start_mono_s REAL NOT NULL,
        start_wall_s REAL NOT NULL,
        start_clock_synced INTEGER NOT NULL,
        ap_timestamp_s INTEGER NOT NULL,
        lon_e7 INTEGER NOT NULL,
        lat_e7 INTEGER NOT NULL,
        alt_mm INTEGER NOT NULL,
        sonar_distance_mm INTEGER NOT NULL,
        sonar_confidence_pct INTEGER NOT NULL,
        planned_depth_m REAL NOT NULL,
        mode TEXT NOT NULL,
        plan_json TEXT NOT NULL,
        end_mono_s REAL,
        end_wall_s REAL,
        end_clock_synced INTEGER,
        outcome TEXT,
        reached_depth_m REAL,
        reason TEXT
    )""",
    """CREATE TABLE samples (
        id INTEGER PRIMARY KEY,
        cast_id INTEGER NOT NULL REFERENCES casts(id),
        mono_s REAL NOT NULL,
        wall_s REAL NOT NULL,
        clock_synced INTEGER NOT NULL,
        depth_m REAL NOT NULL,
        phase TEXT NOT NULL
    )""",
    "CREATE INDEX samples_by_cast ON samples(cast_id, mono_s)",
    """CREATE TABLE events (
        id INTEGER PRIMARY KEY,
        mono_s REAL NOT NULL,
        wall_s REAL NOT NULL,
        clock_synced INTEGER NOT NULL,
        kind TEXT NOT NULL,
        detail_json TEXT NOT NULL
    )""",
    f"PRAGMA application_id = {APPLICATION_ID}",
)

# Version 2: sessions. A monotonic time only means something within the boot
# that produced it, and the Pi has no RTC, so re-timing data later needs to
# know which rows share a boot (and a daemon run). Rows written by v1 keep a
# NULL session: their boot is unknown. Plus an index for `export --since`.
_V2: tuple[str, ...] = (
    """CREATE TABLE sessions (
        id INTEGER PRIMARY KEY,
        boot_id TEXT,
        pid INTEGER NOT NULL,
        software TEXT NOT NULL,
        opened_mono_s REAL NOT NULL,
        opened_wall_s REAL NOT NULL,
        clock_synced INTEGER NOT NULL
    )""",
    "ALTER TABLE fixes ADD COLUMN session_id INTEGER REFERENCES sessions(id)",
    "ALTER TABLE casts ADD COLUMN session_id INTEGER REFERENCES sessions(id)",
    "ALTER TABLE events ADD COLUMN session_id INTEGER REFERENCES sessions(id)",
    "CREATE INDEX fixes_by_wall ON fixes(wall_s)",
    "CREATE INDEX fixes_by_session ON fixes(session_id, mono_s)",
)

# Version 4: which winch produced the data, and whether it was simulated (no
# probe moved), on each session and each cast, so a simulated cast can never be
# taken for a real one. NULL on older rows: not recorded (before version 4 only
# the simulated winch existed, but files may have been copied between runs).
_V4: tuple[str, ...] = (
    "ALTER TABLE sessions ADD COLUMN winch_backend TEXT",
    "ALTER TABLE sessions ADD COLUMN simulated INTEGER",
    "ALTER TABLE casts ADD COLUMN winch_backend TEXT",
    "ALTER TABLE casts ADD COLUMN simulated INTEGER",
)

# Version 5, sonar readings: every distance_simple the daemon's own Ping1D sent
# (`[sonar]`), four a second while it streams. Self-contained: it only adds a
# table and its index, so it can take any place after _V2.
_SONAR_READINGS: tuple[str, ...] = (
    """CREATE TABLE sonar_readings (
        id INTEGER PRIMARY KEY,
        session_id INTEGER REFERENCES sessions(id),
        mono_s REAL NOT NULL,
        wall_s REAL NOT NULL,
        clock_synced INTEGER NOT NULL,
        port TEXT NOT NULL,
        distance_mm INTEGER NOT NULL,
        confidence_pct INTEGER NOT NULL
    )""",
    "CREATE INDEX sonar_readings_by_wall ON sonar_readings(wall_s)",
)

# Version 6: what the deployed firmware adds (issue 8). `measuring_mode` is the
# mode byte of the firmware's 26-byte `M` (NULL for a `T` or a 25-byte `M`);
# `ap_time_s` is the autopilot's clock decoded in the byte order the daemon
# used, named in `ap_time_order` ("big" or "little"), while `ap_timestamp_s`
# stays the two bytes read big-endian as the manual says. Older rows keep NULLs.
_V6: tuple[str, ...] = (
    "ALTER TABLE fixes ADD COLUMN measuring_mode INTEGER",
    "ALTER TABLE fixes ADD COLUMN ap_time_s INTEGER",
    "ALTER TABLE fixes ADD COLUMN ap_time_order TEXT",
)

# MIGRATIONS[n] takes a file from version n to version n + 1. Version 3: the
# sonde's readings (self-contained; see `store.sonde`); version 4: the winch
# backend and whether the data are simulated; version 5: the sonar's readings;
# version 6: the firmware's mode byte and the decoded autopilot clock.
MIGRATIONS: tuple[tuple[str, ...], ...] = (
    _V1,
    _V2,
    sonde.MIGRATION,
    _V4,
    _SONAR_READINGS,
    _V6,
)
SCHEMA_VERSION = len(MIGRATIONS)


class StoreError(CcDaemonError):
    """The journal file cannot be used: missing, not a journal, or from a newer cc-daemon."""


class IncompatibleFileError(StoreError):
    """The file is another program's, or a newer cc-daemon's: this one must never write it.

    Unlike a full disk or a read-only file, waiting does not help; the daemon's
    `Journal` leaves such a file as it is and starts a fresh one beside it.
    """


def file_version(conn: sqlite3.Connection) -> int:
    """The schema version of the open file, after checking that it is a journal (or empty)."""
    app_id = conn.execute("PRAGMA application_id").fetchone()[0]
    version = conn.execute("PRAGMA user_version").fetchone()[0]
    if app_id != APPLICATION_ID:
        has_tables = conn.execute("SELECT count(*) FROM sqlite_master").fetchone()[0] > 0
        if app_id != 0 or has_tables or version != 0:
            raise IncompatibleFileError("not a cc-daemon journal (another program's SQLite file)")
    if version > SCHEMA_VERSION:
        raise IncompatibleFileError(
            f"written by a newer cc-daemon (schema version {version}; "
            f"this one knows up to {SCHEMA_VERSION})"
        )
    return int(version)


def migrate(conn: sqlite3.Connection) -> tuple[int, int]:
    """Bring the file up to `SCHEMA_VERSION` in one transaction; return (from, to).

    The connection must be in autocommit mode (`isolation_level=None`). The
    write lock is taken first (`BEGIN IMMEDIATE`), so this also proves the file
    is writable: a read-only or locked file fails here, not on the first row.
    """
    conn.execute("BEGIN IMMEDIATE")
    try:
        start = file_version(conn)
        for version in range(start, SCHEMA_VERSION):
            for statement in MIGRATIONS[version]:
                conn.execute(statement)
            conn.execute(f"PRAGMA user_version = {version + 1}")
        conn.execute("COMMIT")
    except BaseException:
        # SQLite may already have rolled back by itself (disk full, I/O error).
        if conn.in_transaction:
            conn.execute("ROLLBACK")
        raise
    return start, SCHEMA_VERSION
