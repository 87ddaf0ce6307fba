"""The journal keeps every measurement it can when the disk, the file or the log fails.

Each test makes the real condition: a tiny filesystem that fills up, a log
stream that raises, a corrupt file, a writer thread that has ended, a cast id
that is already taken, a buffer that overflows while the file is unreachable.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import sqlite3
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from structlog.testing import capture_logs

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.ground.logsetup import configure_logging
from cc_daemon.store import Journal, writer
from tests.journalkit import full_journal

FIX = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)
STATION = StartMeasuring(73, -37260600, 404506400, 702000, 6500, 90)
PAGE = 4096  # SQLite's default page size, which the journal keeps


def query(path: Path, sql: str) -> list[tuple[Any, ...]]:
    with contextlib.closing(sqlite3.connect(path)) as conn:
        return conn.execute(sql).fetchall()


def wait_for(predicate: Callable[[], bool], timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"condition not met within {timeout} s")
        time.sleep(0.01)


def free_bytes(path: Path) -> int:
    stat = os.statvfs(path)
    return stat.f_bavail * stat.f_frsize


@contextlib.contextmanager
def tiny_filesystem(where: Path, size: str = "1m") -> Iterator[Path]:
    """A tmpfs of `size` mounted at `where` (root only), unmounted whatever happens."""
    where.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command here: cannot make a tiny filesystem")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        pytest.skip(f"mounting a tmpfs is not permitted here: {done.stderr.strip()}")
    try:
        yield where
    finally:
        if subprocess.run(["umount", str(where)], check=False).returncode != 0:
            subprocess.run(["umount", "-l", str(where)], check=False)


def test_on_a_nearly_full_disk_the_cast_still_lands_after_a_backlog_of_fixes(
    tmp_path: Path,
) -> None:
    with tiny_filesystem(tmp_path / "sd", size="2m") as sd:
        db = sd / "j.db"
        setup = Journal(db)
        setup.open()
        setup.close()
        filler = sd / "filler"  # the rest of the card: photos, logs...
        filler.write_bytes(bytes(free_bytes(sd) - 600 * 1024))
        journal = Journal(db)
        try:
            journal.open()
            for i in range(6000):  # some 600 kB with their indexes and log: more than is free
                journal.record_fix(FIX._replace(timestamp_s=i))
            wait_for(lambda: journal.health().last_error is not None)  # the disk is full
            cast_id = journal.start_cast(STATION, planned_depth_m=2, mode="continuous", plan={})
            for i in range(20):
                journal.record_sample(cast_id, i / 10, "descending")
            journal.end_cast(cast_id, outcome="completed", reached_depth_m=1.9)
            wait_for(lambda: query(db, "SELECT count(*) FROM samples") == [(20,)])
            assert query(db, "SELECT outcome FROM casts") == [("completed",)]
            health = journal.health()
            assert 0 < health.pending_rows < 6000  # what fitted is written; the rest waits
            assert health.pending_rows + health.rows_written == 6022
            assert health.dropped_rows == 0
            assert "full" in (health.last_error or "")

            filler.unlink()  # room again: the backlog follows
            wait_for(lambda: journal.health().pending_rows == 0, timeout=10.0)
        finally:
            journal.close()
        assert query(db, "SELECT count(*) FROM fixes") == [(6000,)]
        assert query(db, "SELECT count(*) FROM samples") == [(20,)]
        assert query(db, "PRAGMA integrity_check") == [("ok",)]


def test_transactions_are_bounded(tmp_path: Path) -> None:
    sizes: list[int] = []
    db = tmp_path / "j.db"
    journal = Journal(db)
    real_write = journal._write

    def counting(rows: list[tuple[object, ...]], *, one_by_one: bool) -> int:
        sizes.append(len(rows))
        return real_write(rows, one_by_one=one_by_one)

    journal._write = counting  # type: ignore[method-assign]
    journal.open()
    for i in range(2300):
        journal.record_fix(FIX._replace(timestamp_s=i))
    journal.close()
    assert sizes and max(sizes) <= writer.MAX_TRANSACTION_ROWS
    assert sum(sizes) == 2300
    assert query(db, "SELECT count(*) FROM fixes") == [(2300,)]


class BrokenStream(io.StringIO):
    """A log stream that can fail like a closed pipe (journald gone) or a full disk."""

    broken = False

    def write(self, text: str) -> int:
        if self.broken:
            raise BrokenPipeError(32, "Broken pipe")
        return super().write(text)

    def isatty(self) -> bool:
        return False


def test_a_log_stream_that_raises_never_stops_the_writer_or_reaches_the_daemon(
    tmp_path: Path,
) -> None:
    stream = BrokenStream()
    configure_logging(level="info", fmt="json", stream=stream)  # undone by conftest
    db = tmp_path / "j.db"
    journal, disk = full_journal(db)
    try:
        journal.open()
        stream.broken = True
        for i in range(3000):  # they do not fit: the writer logs an error, which raises
            journal.record_fix(FIX._replace(timestamp_s=i))
        wait_for(lambda: journal.health().write_errors > 0)
        assert journal.health().writer_alive
        cast_id = journal.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
        journal.record_sample(cast_id, 0.5, "floating")  # misuse: logged, which raises
        journal.record_sample(cast_id, 0.75, "descending")
        journal.record_fix("not a message")  # type: ignore[arg-type]
        wait_for(lambda: query(db, "SELECT count(*) FROM samples") == [(2,)])
        disk.full = False
        wait_for(lambda: journal.health().pending_rows == 0)
        assert journal.health().writer_alive
    finally:
        journal.close()
    assert query(db, "SELECT count(*) FROM fixes") == [(3000,)]


def test_a_writer_that_ended_is_restarted_by_the_next_row(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    journal = Journal(db)
    journal._writer_loop = lambda: None  # type: ignore[method-assign]  # the thread just ends
    try:
        with capture_logs() as logs:
            journal.open()
            wait_for(lambda: not journal.health().writer_alive)
            del journal._writer_loop
            cast_id = journal.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
            journal.record_sample(cast_id, 0.5, "descending")
            wait_for(lambda: journal.health().pending_rows == 0)
        assert journal.health().writer_alive
        assert "journal writer thread had stopped; restarted" in [e["event"] for e in logs]
    finally:
        journal.close()
    assert query(db, "SELECT count(*) FROM samples") == [(1,)]


def test_close_saves_and_reports_rows_a_dead_writer_left(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    journal = Journal(db)
    journal._writer_loop = lambda: None  # type: ignore[method-assign]  # never writes a row
    with capture_logs() as logs:
        journal.open()
        wait_for(lambda: not journal.health().writer_alive)
        journal.record_fix(FIX)
        cast_id = journal.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
        journal.record_sample(cast_id, 0.5, "descending")
        journal.record_event("winch_fault", cast_id=cast_id, detail="stall")
        journal.close()
    (report,) = [e for e in logs if e["event"].startswith("journal closed with rows")]
    assert report["log_level"] == "error"
    assert report["rows"] == 4
    spill = Path(report["spill_file"])
    assert spill.parent == tmp_path
    assert spill.name.startswith("j-unwritten-")
    lines = [json.loads(line) for line in spill.read_text().splitlines()]
    assert [line["table"] for line in lines] == ["casts", "samples", "events", "fixes"]
    assert lines[0]["id"] == cast_id
    assert lines[1]["depth_m"] == 0.5
    assert json.loads(lines[2]["detail_json"]) == {"cast_id": cast_id, "detail": "stall"}
    assert lines[3]["ap_timestamp_s"] == FIX.timestamp_s


def test_rows_go_to_the_state_directory_if_not_beside_the_journal_never_to_tmp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    temp = tmp_path / "tmp"
    temp.mkdir()
    state = tmp_path / "state"
    state.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    monkeypatch.setenv("STATE_DIRECTORY", str(state))
    db = tmp_path / "gone" / "j.db"  # the directory is missing: nothing can be written there
    journal = Journal(db)
    with capture_logs() as logs:
        journal.open()
        for i in range(3):
            journal.record_fix(FIX._replace(timestamp_s=i))
        journal.close()
    (spill,) = state.glob("j-unwritten-*.jsonl")
    assert [json.loads(line)["ap_timestamp_s"] for line in spill.read_text().splitlines()] == [
        0,
        1,
        2,
    ]
    assert any(e.get("spill_file") == str(spill) and e["rows"] == 3 for e in logs)
    # The temporary directory is wiped with the service (PrivateTmp): never used for this.
    assert list(temp.iterdir()) == []


def test_with_nowhere_safe_the_rows_are_reported_lost_not_written_elsewhere(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    temp = tmp_path / "tmp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    journal = Journal(tmp_path / "gone" / "j.db")
    with capture_logs() as logs:
        journal.open()
        journal.record_fix(FIX)
        journal.close()
    assert list(temp.iterdir()) == []
    assert any(
        e["event"] == "journal closed with rows it could not write; they are lost" for e in logs
    )


def test_spill_and_fresh_files_never_go_under_dev_proc_or_sys(tmp_path: Path) -> None:
    from cc_daemon.store.failures import data_directories

    assert data_directories(
        [
            Path("/dev"),
            Path("/proc/self"),
            Path("/sys/kernel"),
            tmp_path,
            tmp_path,
            Path("/dev/shm"),
        ]
    ) == [tmp_path]


def smash_page_headers(db: Path) -> None:
    """Overwrite the start of every page but the first, as a failing SD card might."""
    data = bytearray(db.read_bytes())
    for page in range(1, len(data) // PAGE):
        data[page * PAGE : page * PAGE + 100] = b"\xff" * 100
    db.write_bytes(bytes(data))


def test_a_corrupt_file_is_left_as_it_is_and_the_run_goes_on_in_a_new_one(
    tmp_path: Path,
) -> None:
    db = tmp_path / "j.db"
    first = Journal(db)
    first.open()
    for i in range(2000):
        first.record_fix(FIX._replace(timestamp_s=i))
    old = first.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
    first.end_cast(old, outcome="completed", reached_depth_m=1.0)
    first.close()
    smash_page_headers(db)
    before = db.read_bytes()

    journal = Journal(db)
    with capture_logs() as logs:
        assert journal.open() == []
        cast_id = journal.start_cast(STATION, planned_depth_m=2, mode="stepped", plan={})
        journal.record_sample(cast_id, 1.5, "dwelling")
        journal.end_cast(cast_id, outcome="completed", reached_depth_m=1.5)
        journal.record_fix(FIX)
        wait_for(lambda: journal.health().pending_rows == 0)
        health = journal.health()
        journal.close()
    assert db.read_bytes() == before  # never touched
    assert health.writable
    assert "malformed" in (health.last_error or "")
    new = health.path
    assert new.parent == tmp_path
    assert re.fullmatch(r"j-\d{8}T\d{6}Z(-\d+)?\.db", new.name), new.name
    critical = [e for e in logs if e["log_level"] == "critical"]
    assert critical[0]["path"] == str(db)
    assert critical[-1]["path"] == str(new)
    assert query(new, "SELECT id, mode, outcome FROM casts") == [(cast_id, "stepped", "completed")]
    assert cast_id == 1  # nothing could be read from the old file
    assert query(new, "SELECT depth_m FROM samples") == [(1.5,)]
    assert query(new, "SELECT count(*) FROM fixes") == [(1,)]


def test_a_file_that_goes_bad_mid_cast_is_left_and_the_cast_goes_on_in_a_new_one(
    tmp_path: Path,
) -> None:
    db = tmp_path / "j.db"
    journal = Journal(db)
    try:
        journal.open()
        for i in range(500):
            journal.record_fix(FIX._replace(timestamp_s=i))
        cast_id = journal.start_cast(STATION, planned_depth_m=2, mode="continuous", plan={})
        journal.record_sample(cast_id, 0.25, "soaking")
        wait_for(lambda: journal.health().pending_rows == 0)
        with contextlib.closing(sqlite3.connect(db)) as other:  # all of it into the file
            other.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
        smash_page_headers(db)
        before = db.read_bytes()
        for i in range(1, 5):
            journal.record_sample(cast_id, i / 2, "descending")
        journal.end_cast(cast_id, outcome="completed", reached_depth_m=2.0)
        wait_for(lambda: journal.health().path != db and journal.health().pending_rows == 0)
        health = journal.health()
    finally:
        journal.close()
    assert db.read_bytes() == before
    # Writing works again in the new file: the status has no stale error (issue 20);
    # why the file was left is the journal_unwritable event's.
    assert health.last_error is None
    ((detail,),) = query(health.path, "SELECT detail_json FROM events")
    assert "malformed" in json.loads(detail)["error"]
    # The cast that was running is whole in the new file: its station, samples and end.
    assert query(health.path, "SELECT id, lat_e7, lon_e7, outcome FROM casts") == [
        (cast_id, STATION.lat_e7, STATION.lon_e7, "completed")
    ]
    assert query(health.path, "SELECT cast_id, depth_m FROM samples ORDER BY id") == [
        (cast_id, i / 2) for i in range(1, 5)
    ]


def test_events_follow_a_cast_stored_under_a_new_id(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    first = Journal(db)
    first.open()
    old = first.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
    first.record_event("cast_aborted", cast_id=old, reason="old winch fault")
    first.end_cast(old, outcome="aborted", reached_depth_m=1.0, reason="winch")
    first.close()
    db.rename(tmp_path / "aside.db")  # the file is unavailable when the daemon starts
    db.mkdir()
    second = Journal(db)
    try:
        second.open()
        new = second.start_cast(STATION, planned_depth_m=2, mode="stepped", plan={})
        second.record_event("cast_aborted", cast_id=new, reason="new winch fault")
        second.record_event("port_lost", port="/dev/ttyUSB0")
        second.end_cast(new, outcome="aborted", reached_depth_m=2.0, reason="winch")
        wait_for(lambda: second.health().write_errors > 0)
        db.rmdir()
        (tmp_path / "aside.db").rename(db)
        wait_for(lambda: second.health().pending_rows == 0)
    finally:
        second.close()
    assert new == old == 1
    assert query(db, "SELECT id, mode FROM casts ORDER BY id") == [
        (1, "continuous"),
        (2, "stepped"),
    ]
    events = [
        (kind, json.loads(d))
        for kind, d in query(db, "SELECT kind, detail_json FROM events")
        if kind != "journal_unwritable"  # the failed open, journaled once it worked
    ]
    assert events == [
        ("cast_aborted", {"cast_id": 1, "reason": "old winch fault"}),
        ("cast_aborted", {"cast_id": 2, "reason": "new winch fault"}),
        ("port_lost", {"port": "/dev/ttyUSB0"}),
    ]


def test_one_bound_holds_over_every_unwritten_row_and_the_oldest_fixes_go_first(
    tmp_path: Path,
) -> None:
    db = tmp_path / "not-yet" / "j.db"
    journal = Journal(db, max_buffered_rows=50)
    try:
        journal.open()
        for i in range(40):
            journal.record_fix(FIX._replace(timestamp_s=i))
        wait_for(lambda: journal.health().write_errors > 1)  # the writer has had them
        cast_id = journal.start_cast(STATION, planned_depth_m=3, mode="continuous", plan={})
        for i in range(30):
            journal.record_sample(cast_id, i / 10, "descending")
            journal.record_fix(FIX._replace(timestamp_s=40 + i))
        health = journal.health()
        assert health.pending_rows <= 50
        assert health.pending_rows + health.dropped_rows == 101
        db.parent.mkdir()
        wait_for(lambda: journal.health().pending_rows == 0)
    finally:
        journal.close()
    assert query(db, "SELECT count(*) FROM samples") == [(30,)]
    kept = [t for (t,) in query(db, "SELECT ap_timestamp_s FROM fixes ORDER BY id")]
    assert kept == list(range(70 - len(kept), 70))  # the newest, none missing among them
