"""A store that cannot be written never reaches the daemon, and catches up when it clears.

Each test makes a real condition on a real file: a read-only file, a
read-only directory, a full database, a file from a newer cc-daemon, a file
that is not a journal (those two are left untouched and the rows go to a new
file beside them). As root, permission bits do not stop writes, so the
read-only cases also set the immutable attribute (`chattr +i`), which does;
where neither works, the test is skipped rather than passed.

"Full" is SQLite's own SQLITE_FULL ("database or disk is full"), produced by
`PRAGMA max_page_count` on the journal's connection: the error a full SD card
gives, without mounting a tiny filesystem.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sqlite3
import stat
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from structlog.testing import capture_logs

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.store import Journal, failures
from cc_daemon.store.schema import APPLICATION_ID
from tests.journalkit import full_journal

FIX = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)
STATION = StartMeasuring(73, -37260600, 404506400, 702000, 6500, 90)


def query(path: Path, sql: str) -> list[tuple[object, ...]]:
    with contextlib.closing(sqlite3.connect(path)) as conn:
        return conn.execute(sql).fetchall()


def wait_for(predicate: Callable[[], bool], timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"condition not met within {timeout} s")
        time.sleep(0.01)


def _chattr(flag: str, path: Path) -> bool:
    if shutil.which("chattr") is None:
        return False
    done = subprocess.run(["chattr", flag, str(path)], capture_output=True, check=False)
    return done.returncode == 0


def _writable(path: Path) -> bool:
    try:
        if path.is_dir():
            probe = path / ".probe"
            probe.touch()
            probe.unlink()
        else:
            with path.open("r+b"):
                pass
    except PermissionError:
        return False
    return True


@contextlib.contextmanager
def read_only(path: Path) -> Iterator[Callable[[], None]]:
    """Make `path` read-only for this process (root included); yield what undoes it."""
    mode = stat.S_IMODE(path.stat().st_mode)
    immutable = False

    def clear() -> None:
        nonlocal immutable
        if immutable:
            _chattr("-i", path)
            immutable = False
        path.chmod(mode)

    path.chmod(0o555 if path.is_dir() else 0o444)
    if os.geteuid() == 0:
        immutable = _chattr("+i", path)
    try:
        if _writable(path):
            clear()
            pytest.skip("cannot make a file read-only here (root without chattr +i)")
        yield clear
    finally:
        clear()


def record_a_cast(journal: Journal) -> int:
    journal.record_fix(FIX)
    cast_id = journal.start_cast(STATION, planned_depth_m=2, mode="continuous", plan={})
    for i in range(5):
        journal.record_sample(cast_id, i / 2, "descending")
    journal.end_cast(cast_id, outcome="completed", reached_depth_m=2.0)
    journal.record_event("port_lost", port="/dev/ttyUSB0")
    return cast_id


def test_a_read_only_file_is_written_once_it_is_writable_again(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    first = Journal(db)
    first.open()
    first.record_fix(FIX)
    first.close()
    with read_only(db) as clear:
        journal = Journal(db)
        try:
            assert journal.open() == []  # no exception: the error is logged
            cast_id = record_a_cast(journal)
            health = journal.health()
            assert not health.writable
            # SQLite opens the file read-only, then refuses the first write.
            assert "readonly database" in (health.last_error or "")
            assert health.pending_rows == 9
            clear()
            wait_for(lambda: journal.health().pending_rows == 0)
            assert journal.health().writable
        finally:
            journal.close()
    assert query(db, "SELECT count(*) FROM fixes") == [(2,)]
    assert query(db, "SELECT id, outcome FROM casts") == [(cast_id, "completed")]
    assert query(db, "SELECT count(*) FROM samples") == [(5,)]


def test_a_read_only_directory_is_written_once_it_is_writable_again(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    db = state / "cc-daemon.db"
    with read_only(state) as clear:
        journal = Journal(db)
        try:
            with capture_logs() as logs:
                assert journal.open() == []
            assert logs[0]["event"] == "journal cannot be opened; keeping rows in memory"
            assert logs[0]["log_level"] == "error"
            record_a_cast(journal)
            wait_for(lambda: journal.health().write_errors >= 2)  # a retry or two fail
            assert not db.exists()
            clear()
            wait_for(lambda: journal.health().pending_rows == 0)
        finally:
            journal.close()
    assert query(db, "SELECT count(*) FROM samples") == [(5,)]
    # The episode is journaled once the file takes rows again (issue 20).
    kinds = [kind for (kind,) in query(db, "SELECT kind FROM events")]
    assert kinds == ["port_lost", "journal_unwritable"]


def test_a_full_store_keeps_rows_in_memory_until_there_is_room(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    journal, disk = full_journal(db)
    try:
        journal.open()
        for i in range(3000):  # some 150 kB: far more than the free pages
            journal.record_fix(FIX._replace(timestamp_s=i))
        cast_id = record_a_cast(journal)
        wait_for(lambda: journal.health().write_errors > 0)
        health = journal.health()
        assert "database or disk is full" in (health.last_error or "")
        assert not health.writable
        # What fitted is in the file, the cast first; only the rest waits.
        assert health.pending_rows + health.rows_written == 3009
        assert health.pending_rows > 2500
        assert query(db, "SELECT count(*) FROM samples") == [(5,)]
        assert query(db, "SELECT outcome FROM casts") == [("completed",)]
        disk.full = False  # room again: the next reconnect sets no cap
        # Every row, then the episode's event, which the writer records on its own
        # thread after the pass that succeeded (wait for both before closing).
        wait_for(lambda: journal.health().rows_written == 3010)
        health = journal.health()
        assert health.writable and health.pending_rows == 0
        assert health.last_error is None  # the status says what is true now
    finally:
        journal.close()
    # 3009 rows, and the episode of the full disk as an event once there was room.
    assert journal.health().rows_written == 3010
    ((detail,),) = query(db, "SELECT detail_json FROM events WHERE kind = 'journal_unwritable'")
    episode = json.loads(detail)
    assert "database or disk is full" in episode["error"]
    assert episode["dropped_rows"] == 0
    assert episode["seconds"] > 0
    assert query(db, "SELECT count(*) FROM fixes") == [(3001,)]
    assert query(db, "SELECT count(*) FROM samples WHERE cast_id = 1") == [(5,)]
    assert cast_id == 1


def test_a_file_from_a_newer_daemon_is_never_touched(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    with contextlib.closing(sqlite3.connect(db)) as conn:
        conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
        conn.execute("PRAGMA user_version = 99")
        conn.execute("CREATE TABLE future (x)")
        conn.commit()
    before = db.read_bytes()
    journal = Journal(db)
    with capture_logs() as logs:
        assert journal.open() == []
        cast_id = record_a_cast(journal)
        journal.close()
    health = journal.health()
    assert "newer cc-daemon" in (health.last_error or "")
    assert db.read_bytes() == before
    # The run is kept in a new file beside it, which the log names.
    assert health.path.parent == tmp_path
    assert health.path.name.startswith("j-")
    critical = [e for e in logs if e["log_level"] == "critical"]
    assert [e["path"] for e in critical] == [str(db), str(health.path)]
    assert query(health.path, "SELECT id, outcome FROM casts") == [(cast_id, "completed")]
    assert query(health.path, "SELECT count(*) FROM samples") == [(5,)]
    assert query(health.path, "SELECT count(*) FROM fixes") == [(1,)]


def test_an_unusable_file_in_a_read_only_directory_is_replaced_in_the_temporary_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    temp = tmp_path / "tmp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    state = tmp_path / "state"
    state.mkdir()
    db = state / "j.db"
    db.write_bytes(b"not a database" * 500)
    before = db.read_bytes()
    with read_only(state):
        journal = Journal(db)
        try:
            journal.open()
            cast_id = record_a_cast(journal)
            wait_for(lambda: journal.health().pending_rows == 0)
            health = journal.health()
        finally:
            journal.close()
    assert db.read_bytes() == before
    assert health.path.parent == temp
    assert query(health.path, "SELECT id FROM casts") == [(cast_id,)]
    assert query(health.path, "SELECT count(*) FROM samples") == [(5,)]


@pytest.mark.parametrize("kind", ["garbage", "other sqlite"])
def test_a_file_that_is_not_a_journal_is_never_touched(tmp_path: Path, kind: str) -> None:
    db = tmp_path / "j.db"
    if kind == "garbage":
        db.write_bytes(b"field notes, not a database\n" * 200)
    else:
        with contextlib.closing(sqlite3.connect(db)) as conn:
            conn.execute("CREATE TABLE notes (text)")
            conn.commit()
    before = db.read_bytes()
    journal = Journal(db)
    journal.open()
    journal.record_fix(FIX)
    journal.close()
    health = journal.health()
    assert health.write_errors >= 1
    assert db.read_bytes() == before
    assert health.path != db
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["j.db", health.path.name])
    assert query(health.path, "SELECT count(*) FROM fixes") == [(1,)]


def test_repeated_errors_are_rate_limited_never_silenced(monkeypatch: pytest.MonkeyPatch) -> None:
    now = [100.0]
    limiter = failures.RateLimitedLog(0.3, clock=lambda: now[0])
    with capture_logs() as logs:
        for _ in range(5):
            limiter.error("same", "journal write failed", error="disk full")
            now[0] += 0.01
        limiter.error("other", "journal buffer full")
        now[0] += 0.35
        limiter.error("same", "journal write failed", error="disk full")
    assert [(e["event"], e.get("repeated")) for e in logs] == [
        ("journal write failed", None),
        ("journal buffer full", None),
        ("journal write failed", 4),
    ]


def test_an_episode_that_ends_at_close_is_journaled_too(tmp_path: Path) -> None:
    # The disk has room again just as the daemon stops: the writer's last pass,
    # at close, writes the backlog and ends the episode; its event goes in too.
    db = tmp_path / "j.db"
    journal, disk = full_journal(db)
    try:
        journal.open()
        for i in range(3000):
            journal.record_fix(FIX._replace(timestamp_s=i))
        wait_for(lambda: journal.health().write_errors > 0)
        disk.full = False
    finally:
        journal.close()  # at once: no retry pass came between
    assert journal.health().dropped_rows == 0
    kinds = [kind for (kind,) in query(db, "SELECT kind FROM events")]
    assert kinds == ["journal_unwritable"]
