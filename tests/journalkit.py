"""Test kit for the journal: a database that is "full" for as long as a test says,
and real journals damaged as storage damages them.

"Full" is SQLite's own SQLITE_FULL ("database or disk is full"): while the
switch is on, every new connection caps the file at its current page count,
so it cannot grow by a single page. Turned off, the next reconnect sets no cap.
"""

from __future__ import annotations

import contextlib
import random
import shutil
import sqlite3
import time
from collections.abc import Callable
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


# ------------------------------------------------------------ damaged journals
# Real damage done to real journal files, as storage does it: the tests read
# them with every data command and salvage them with `cc-daemon recover`.

SECTOR = 512


def survey_journal(db: Path, *, casts: int = 17, keep_wal: bool = False) -> None:
    """A real journal of a survey with `casts` casts (about 300 s apart).

    With `keep_wal`, `db` and its `-wal` are copied while the writer still has
    them open (as a power cut leaves them): most rows are then in the log only.
    """
    from cc_daemon.store.synthetic import FakeClock, write_survey

    clock = FakeClock()
    build = db.with_name(f"build-{db.name}")
    journal = Journal(build, monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    try:
        write_survey(journal, clock, duration_s=300 * casts - 150, cast_every_s=300)
        deadline = time.monotonic() + 30
        while journal.health().pending_rows and time.monotonic() < deadline:
            time.sleep(0.01)
        if keep_wal:
            shutil.copyfile(build, db)
            shutil.copyfile(f"{build}-wal", f"{db}-wal")
    finally:
        journal.close()
    if not keep_wal:
        shutil.move(build, db)
    else:
        build.unlink()


def page_size(db: Path) -> int:
    return int.from_bytes(db.read_bytes()[16:18], "big") or 65536


def garble_page(db: Path, page: int, seed: int = 1) -> None:
    """Random bytes over page `page` (1-based) of the file."""
    size = page_size(db)
    data = bytearray(db.read_bytes())
    rng = random.Random(seed)
    at = (page - 1) * size
    data[at : at + size] = rng.randbytes(size)
    db.write_bytes(bytes(data))


def wipe_sector(db: Path, sector: int) -> None:
    """Zeros over one 512-byte sector, as a failing card returns them."""
    with db.open("r+b") as f:
        f.seek(sector * SECTOR)
        f.write(bytes(SECTOR))


def truncate(db: Path, fraction: float) -> None:
    """Cut the file to `fraction` of its length (on a page boundary)."""
    size = page_size(db)
    keep = int(db.stat().st_size * fraction) // size * size
    with db.open("r+b") as f:
        f.truncate(keep)


def flip_wal_byte(db: Path, frame: int) -> None:
    """Flip one byte in the page data of frame `frame` (1-based) of `db`'s -wal."""
    wal = Path(f"{db}-wal")
    data = bytearray(wal.read_bytes())
    size = int.from_bytes(data[8:12], "big")
    at = 32 + (frame - 1) * (24 + size) + 24 + size // 2
    data[at] ^= 0xFF
    wal.write_bytes(bytes(data))


def sql(db: Path, *statements: str) -> None:
    """Run statements on the file directly (as another program would)."""
    with contextlib.closing(sqlite3.connect(db, isolation_level=None)) as conn:
        for statement in statements:
            conn.execute(statement)


# The damaged forms of a journal, each a function of its path.
DAMAGE: dict[str, Callable[[Path], None]] = {
    "no-casts-table": lambda db: sql(db, "DROP TABLE casts"),
    "no-samples-table": lambda db: sql(db, "DROP TABLE samples"),
    "no-events-table": lambda db: sql(db, "DROP TABLE events"),
    "no-sonde-table": lambda db: sql(db, "DROP TABLE sonde_samples"),
    "bad-utf8-text": lambda db: sql(
        db,
        "UPDATE events SET kind = CAST(x'6bff6e64' AS TEXT) WHERE id % 2 = 0",
        "UPDATE samples SET phase = CAST(x'c3' AS TEXT) WHERE id % 7 = 0",
    ),
    "bytes-in-json": lambda db: sql(
        db,
        "UPDATE casts SET plan_json = x'00ff10' WHERE id = 2",
        "UPDATE events SET detail_json = x'fffe' WHERE id = 1",
    ),
    "garbled-page": lambda db: garble_page(db, 5),
    "truncated": lambda db: truncate(db, 0.6),
}


# ------------------------------------------------------------ hostile journals
# A journal copied from someone else (scp, a USB stick): real files made hostile
# as an attacker would, read by every data command (tests/test_journal_hostile*.py).

RECURSIVE_VIEW = (
    "WITH RECURSIVE r(n) AS (SELECT 1 UNION ALL SELECT n + 1 FROM r) SELECT {columns} FROM r"
)


def view_in_place_of(db: Path, table: str, body: str) -> None:
    """Rename `table` away and put a view of the same name and columns in its place;
    `body` is the view's SELECT, `{columns}` standing for the table's columns (each
    given the value `n`, the recursion's counter, or NULL for text)."""
    with contextlib.closing(sqlite3.connect(db, isolation_level=None)) as conn:
        info = conn.execute(f"PRAGMA table_info({table})").fetchall()
        columns = ", ".join(f"{'NULL' if row[2] == 'TEXT' else 'n'} AS {row[1]}" for row in info)
        conn.execute(f"ALTER TABLE {table} RENAME TO {table}_real")
        conn.execute(f"CREATE VIEW {table} AS {body.format(columns=columns, table=table)}")


def endless_view(db: Path, table: str) -> None:
    """`table` replaced by a view that never ends (a recursive CTE without a limit)."""
    view_in_place_of(db, table, RECURSIVE_VIEW)


def self_join_view(db: Path, table: str, ways: int = 12) -> None:
    """`table` replaced by a `ways`-way self-join of its rows: rows ** ways rows."""
    with contextlib.closing(sqlite3.connect(db, isolation_level=None)) as conn:
        names = [row[1] for row in conn.execute(f"PRAGMA table_info({table})")]
        conn.execute(f"ALTER TABLE {table} RENAME TO {table}_real")
        picked = ", ".join(f"t0.{name} AS {name}" for name in names)
        joined = ", ".join(f"{table}_real t{i}" for i in range(ways))
        conn.execute(f"CREATE VIEW {table} AS SELECT {picked} FROM {joined}")


def huge_text(db: Path, table: str, column: str, size: int, where: str = "id = 1") -> None:
    """One cell of `size` characters (built by SQLite, never in this process's memory)."""
    sql(
        db,
        f"UPDATE {table} SET {column} = substr(hex(zeroblob({(size + 1) // 2})), 1, {size})"
        f" WHERE {where}",
    )


def deep_json(depth: int) -> str:
    return "[" * depth + "]" * depth


HOSTILE_VALUES: dict[str, Callable[[Path], None]] = {
    "no-fixes-table": lambda db: sql(db, "DROP TABLE fixes"),
    "deep-json": lambda db: sql(
        db,
        f"UPDATE events SET detail_json = '{deep_json(50_000)}' WHERE id = 1",
        f"UPDATE casts SET plan_json = '{deep_json(50_000)}' WHERE id = 2",
    ),
    "text-in-times": lambda db: sql(
        db,
        "UPDATE sessions SET opened_wall_s = 'yesterday'",
        "UPDATE fixes SET wall_s = 'noon' WHERE id % 5 = 0",
        "UPDATE samples SET wall_s = x'00ff' WHERE id % 7 = 0",
    ),
    "times-of-1e308": lambda db: sql(
        db,
        "UPDATE fixes SET wall_s = 1e308 WHERE id % 3 = 0",
        "UPDATE casts SET end_wall_s = 1e308 WHERE id = 2",
        "UPDATE events SET wall_s = -1e308 WHERE id = 1",
        "UPDATE samples SET wall_s = 1e308 WHERE id % 11 = 0",
    ),
}
