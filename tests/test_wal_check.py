"""The log's frames are checked one at a time, once: a log that only grew is checked
from where the last check stopped (issue 27).

A real write-ahead log, kept by a writer that never checkpoints (as the daemon's
between two checkpoints), grows between two checks; what the second check reads
is counted by the kernel (`/proc/self/io`), and damage in a frame written after
the first check is still found.
"""

from __future__ import annotations

import contextlib
import sqlite3
from collections.abc import Iterator
from pathlib import Path

import pytest

from cc_daemon.store.walcheck import WalCheck
from tests.journalkit import flip_wal_byte


def read_so_far() -> int:
    for line in Path("/proc/self/io").read_text().splitlines():
        if line.startswith("rchar:"):
            return int(line.split()[1])
    raise AssertionError("no rchar in /proc/self/io")


@pytest.fixture
def writer(tmp_path: Path) -> Iterator[tuple[Path, sqlite3.Connection]]:
    db = tmp_path / "log.db"
    conn = sqlite3.connect(db, isolation_level=None)
    conn.execute("PRAGMA journal_mode = WAL")
    conn.execute("PRAGMA wal_autocheckpoint = 0")  # the log only grows
    conn.execute("CREATE TABLE t (id INTEGER PRIMARY KEY, v BLOB)")
    with contextlib.closing(conn):
        yield db, conn


def grow(conn: sqlite3.Connection, rows: int) -> None:
    for _ in range(rows):  # a commit each: a frame or two each
        conn.execute("INSERT INTO t (v) VALUES (randomblob(3000))")


def test_a_log_that_grew_is_checked_from_where_the_last_check_stopped(
    writer: tuple[Path, sqlite3.Connection],
) -> None:
    db, conn = writer
    grow(conn, 400)
    wal = Path(f"{db}-wal")
    check = WalCheck()
    before = read_so_far()
    assert check(db) is None
    first = read_so_far() - before
    assert first >= wal.stat().st_size * 0.9  # every frame read once
    size = wal.stat().st_size
    grow(conn, 20)
    before = read_so_far()
    assert check(db) is None
    second = read_so_far() - before
    added = wal.stat().st_size - size
    assert second < added + 16_384  # the new frames, not the whole log again
    assert second < first / 5
    grow(conn, 10)
    frames = (wal.stat().st_size - 32) // (4096 + 24)
    flip_wal_byte(db, frame=frames - 3)  # written since the last check; frames follow it
    said = check(db)
    assert said is not None and "the write-ahead log is damaged at frame" in said
    assert said == WalCheck()(db)  # the same verdict as a check from the start


def test_a_frame_read_while_the_daemon_wrote_it_is_read_again_not_called_damage(
    writer: tuple[Path, sqlite3.Connection], monkeypatch: pytest.MonkeyPatch
) -> None:
    # Seen beside a writing daemon (tests/test_snapshot.py, an idle make test): the
    # check read a frame half written, then the frames written after it, and said the
    # log was damaged at frame 65 of 1005. Here the "writer" finishes the frame while
    # the check waits to read it again.
    from cc_daemon.store import walcheck

    db, conn = writer
    grow(conn, 60)
    wal = Path(f"{db}-wal")
    whole = wal.read_bytes()
    flip_wal_byte(db, frame=20)  # as read in flight
    monkeypatch.setattr(walcheck, "_settle", lambda: wal.write_bytes(whole), raising=False)
    assert WalCheck()(db) is None
    # A frame that stays bad is damage all the same, after the rereads.
    flip_wal_byte(db, frame=20)
    waits: list[int] = []
    monkeypatch.setattr(walcheck, "_settle", lambda: waits.append(1))
    said = WalCheck()(db)
    assert said is not None and "damaged at frame 20 of" in said
    assert len(waits) == walcheck._ATTEMPTS
