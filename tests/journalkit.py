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
