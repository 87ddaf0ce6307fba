"""The journal stores what the daemon records, when it should, without blocking it."""

from __future__ import annotations

import contextlib
import json
import sqlite3
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from structlog.testing import capture_logs

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.store import Journal, default_store_path, writer
from cc_daemon.store.synthetic import FakeClock

FIX = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)
STATION = StartMeasuring(73, -37260600, 404506400, 702000, 6500, 90)

MakeJournal = Callable[..., Journal]


@pytest.fixture
def make_journal() -> Iterator[MakeJournal]:
    """Build journals that are closed at the end of the test, whatever happens."""
    made: list[Journal] = []

    def make(path: Path, **kwargs: Any) -> Journal:
        journal = Journal(path, **kwargs)
        made.append(journal)
        return journal

    yield make
    for journal in made:
        journal.close()


def query(path: Path, sql: str, params: tuple[object, ...] = ()) -> list[tuple[Any, ...]]:
    with contextlib.closing(sqlite3.connect(path)) as conn:
        return conn.execute(sql, params).fetchall()


def wait_for(predicate: Callable[[], bool], timeout: float = 30.0) -> float:
    """Poll until `predicate()` holds; return the seconds it took (fail on timeout)."""
    start = time.monotonic()
    while not predicate():
        if time.monotonic() - start > timeout:
            pytest.fail(f"condition not met within {timeout} s")
        time.sleep(0.01)
    return time.monotonic() - start


def test_rows_written_match_what_was_recorded(tmp_path: Path, make_journal: MakeJournal) -> None:
    clock = FakeClock()
    db = tmp_path / "j.db"
    journal = make_journal(db, monotonic=clock.monotonic, wall=clock.wall)
    assert journal.open() == []

    journal.record_fix(FIX)
    clock.advance(1.0)
    journal.record_fix(STATION)
    plan: dict[str, object] = {"target_depth_m": 5.0, "where": tmp_path}
    cast_id = journal.start_cast(STATION, planned_depth_m=6.0, mode="stepped", plan=plan)
    for depth, phase in [(0.5, "soaking"), (1.25, "descending"), (6.0, "dwelling")]:
        clock.advance(1.0)
        journal.record_sample(cast_id, depth, phase)
    clock.advance(1.0)
    journal.record_event("winch_fault", detail="stall", depth_m=6.0)
    journal.end_cast(cast_id, outcome="aborted", reached_depth_m=6.0, reason="winch stalled")
    journal.close()

    assert journal.health().rows_written == 8
    fixes = query(
        db,
        "SELECT mono_s, wall_s, clock_synced, frame, ap_timestamp_s, lon_e7, lat_e7, alt_mm,"
        " sonar_distance_mm, sonar_confidence_pct, session_id FROM fixes ORDER BY id",
    )
    wall0 = FakeClock().wall()
    assert fixes == [
        (1000.0, wall0, 0, "P-T", *FIX, 1),
        (1001.0, wall0 + 1, 0, "P-M", *STATION[:6], 1),
    ]
    (cast,) = query(
        db,
        "SELECT id, start_mono_s, ap_timestamp_s, lon_e7, lat_e7, alt_mm, sonar_distance_mm,"
        " sonar_confidence_pct, planned_depth_m, mode, plan_json, end_mono_s, end_wall_s,"
        " outcome, reached_depth_m, reason, session_id FROM casts",
    )
    assert cast[:10] == (cast_id, 1001.0, *STATION[:6], 6.0, "stepped")
    assert json.loads(cast[10]) == {"target_depth_m": 5.0, "where": str(tmp_path)}
    assert cast[11:] == (1005.0, wall0 + 5, "aborted", 6.0, "winch stalled", 1)
    assert query(db, "SELECT cast_id, mono_s, depth_m, phase FROM samples ORDER BY id") == [
        (cast_id, 1002.0, 0.5, "soaking"),
        (cast_id, 1003.0, 1.25, "descending"),
        (cast_id, 1004.0, 6.0, "dwelling"),
    ]
    ((kind, detail, mono),) = query(db, "SELECT kind, detail_json, mono_s FROM events")
    assert (kind, json.loads(detail), mono) == (
        "winch_fault",
        {"detail": "stall", "depth_m": 6.0},
        1005.0,
    )
    ((boot_id, software),) = query(db, "SELECT boot_id, software FROM sessions")
    assert software.startswith("cc-daemon ")
    boot_file = Path("/proc/sys/kernel/random/boot_id")
    if boot_file.exists():
        assert boot_id == boot_file.read_text().strip()


def test_every_row_says_whether_the_clock_was_synchronised(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    clock = FakeClock()
    synced = [False]

    def kernel_says() -> bool:  # as clocksync.clock_synced answers, from adjtimex
        return synced[0]

    db = tmp_path / "j.db"
    journal = make_journal(db, monotonic=clock.monotonic, wall=clock.wall, clock_synced=kernel_says)
    journal.open()
    journal.record_fix(FIX)
    synced[0] = True  # chrony (or timesyncd, or GPS time) got its sync
    clock.advance(0.5)
    journal.record_fix(FIX)  # asked once a second at most: still the old answer
    clock.advance(0.5)
    journal.record_fix(FIX)
    cast_id = journal.start_cast(STATION, planned_depth_m=1.0, mode="continuous", plan={})
    journal.record_sample(cast_id, 0.5, "descending")
    journal.close()
    assert query(db, "SELECT clock_synced FROM fixes ORDER BY id") == [(0,), (0,), (1,)]
    assert query(db, "SELECT start_clock_synced FROM casts") == [(1,)]
    assert query(db, "SELECT clock_synced FROM samples") == [(1,)]
    assert query(db, "SELECT clock_synced FROM sessions") == [(0,)]  # asked at open, too


def test_a_failing_clock_question_is_an_unsynchronised_clock_not_a_crash(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    def broken() -> bool:
        raise OSError("adjtimex: no such thing")

    db = tmp_path / "j.db"
    journal = make_journal(db, clock_synced=broken)
    journal.open()
    journal.record_fix(FIX)
    journal.close()
    assert query(db, "SELECT clock_synced FROM fixes") == [(0,)]


def test_default_store_path_follows_systemd(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    assert default_store_path() == Path("cc-daemon.db")
    monkeypatch.setenv("STATE_DIRECTORY", "/var/lib/cc-daemon")
    assert default_store_path() == Path("/var/lib/cc-daemon/cc-daemon.db")
    monkeypatch.setenv("STATE_DIRECTORY", "/var/lib/cc-daemon:/var/lib/other")
    assert default_store_path() == Path("/var/lib/cc-daemon/cc-daemon.db")


def test_cast_ids_continue_after_the_last_one_in_the_file(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    db = tmp_path / "j.db"
    first = make_journal(db)
    first.open()
    ids = [first.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={}) for _ in "ab"]
    for cast_id in ids:
        first.end_cast(cast_id, outcome="completed", reached_depth_m=1.0)
    first.close()
    second = make_journal(db)
    assert second.open() == []
    assert second.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={}) == 3
    assert ids == [1, 2]


def test_a_fix_reaches_the_file_within_the_flush_interval(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    db = tmp_path / "j.db"
    journal = make_journal(db)
    journal.open()
    journal.record_fix(FIX)
    took = wait_for(lambda: query(db, "SELECT count(*) FROM fixes") == [(1,)], timeout=30)
    # One flush interval (1 s) on an idle machine; the rule is 10 s (docs/data.md).
    assert took < 10.0


def test_cast_rows_are_committed_at_once_with_synchronous_full(
    tmp_path: Path, make_journal: MakeJournal, monkeypatch: pytest.MonkeyPatch
) -> None:
    statements: list[str] = []

    def trace(conn: sqlite3.Connection) -> None:
        conn.set_trace_callback(statements.append)

    db = tmp_path / "j.db"
    journal = make_journal(db, on_connect=trace)
    journal.open()
    for count in (1, 2):  # the first commit is FULL whatever it holds; the next fix is not
        journal.record_fix(FIX)
        wait_for(lambda n=count: query(db, "SELECT count(*) FROM fixes") == [(n,)])  # type: ignore[misc]
    # From the next pass on, the writer sleeps ten minutes between flushes: a cast row
    # that arrives within 30 s was written because it woke the writer, whatever the load.
    monkeypatch.setattr(writer, "FLUSH_INTERVAL_S", 600.0)
    journal.record_fix(FIX)  # written at the pass already due, which then waits 600 s
    wait_for(lambda: query(db, "SELECT count(*) FROM fixes") == [(3,)], timeout=30)
    cast_id = journal.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
    journal.record_sample(cast_id, 0.25, "descending")
    wait_for(lambda: query(db, "SELECT count(*) FROM samples") == [(1,)], timeout=30)
    journal.close()

    def sync_mode_at_last(insert: str) -> str:
        at = max(i for i, s in enumerate(statements) if s.startswith(insert))
        pragmas = [s for s in statements[:at] if s.startswith("PRAGMA synchronous")]
        return pragmas[-1].split("=")[1].strip()

    assert sync_mode_at_last("INSERT INTO samples") == "FULL"
    assert sync_mode_at_last("INSERT INTO casts") == "FULL"
    assert sync_mode_at_last("INSERT INTO fixes") == "NORMAL"


def test_recording_does_not_wait_for_a_locked_file(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    db = tmp_path / "j.db"
    journal = make_journal(db)
    journal.open()
    with contextlib.closing(sqlite3.connect(db, isolation_level=None)) as other:
        other.execute("BEGIN IMMEDIATE")  # holds the write lock: the writer must wait
        start = time.perf_counter()
        for _ in range(2000):
            journal.record_fix(FIX)
        cast_id = journal.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
        for i in range(100):
            journal.record_sample(cast_id, i / 100, "descending")
        took = time.perf_counter() - start
        wait_for(lambda: journal.health().write_errors > 0)
        health = journal.health()
        assert not health.writable
        assert "locked" in (health.last_error or "")
        assert health.pending_rows == 2101
        other.execute("ROLLBACK")
    # Microseconds each (about 2 ms for all 2,101 on an idle machine). A call waiting
    # for the lock would take the writer's busy timeout at least: not even 20 of them did.
    assert took < 20 * writer.BUSY_TIMEOUT_S
    wait_for(lambda: journal.health().pending_rows == 0)
    assert journal.health().writable
    assert query(db, "SELECT count(*) FROM fixes") == [(2000,)]
    assert query(db, "SELECT count(*) FROM samples") == [(100,)]


def test_a_full_buffer_drops_the_oldest_telemetry_and_keeps_every_sample(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    clock = FakeClock()
    db = tmp_path / "not-yet" / "j.db"  # the directory is missing: nothing can be written
    journal = make_journal(db, monotonic=clock.monotonic, wall=clock.wall, max_buffered_rows=50)
    with capture_logs() as logs:
        journal.open()
        cast_id = journal.start_cast(STATION, planned_depth_m=3, mode="continuous", plan={})
        for i in range(30):
            journal.record_sample(cast_id, i / 10, "descending")
        for i in range(100):
            clock.advance(1.0)
            journal.record_fix(FIX._replace(timestamp_s=i))
        wait_for(lambda: journal.health().write_errors > 1)  # a writer pass has trimmed too
    health = journal.health()
    assert health.pending_rows <= 50
    assert health.pending_rows + health.dropped_rows == 131
    assert any(e["event"] == "journal buffer full; oldest rows dropped" for e in logs)

    db.parent.mkdir()
    wait_for(lambda: journal.health().pending_rows == 0)
    assert query(db, "SELECT count(*) FROM casts") == [(1,)]
    assert query(db, "SELECT count(*) FROM samples") == [(30,)]
    kept = query(db, "SELECT ap_timestamp_s FROM fixes ORDER BY id")
    assert kept == [(i,) for i in range(100 - len(kept), 100)]  # the newest ones
    assert len(kept) == health.pending_rows - 31


def test_samples_go_only_when_nothing_else_is_left_and_cast_rows_never(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    db = tmp_path / "not-yet" / "j.db"
    journal = make_journal(db, max_buffered_rows=10)
    journal.open()
    cast_id = journal.start_cast(STATION, planned_depth_m=3, mode="continuous", plan={})
    for i in range(20):
        journal.record_sample(cast_id, float(i), "descending")
    journal.end_cast(cast_id, outcome="completed", reached_depth_m=19.0)
    wait_for(lambda: journal.health().write_errors > 1)
    health = journal.health()
    assert health.pending_rows <= 10
    db.parent.mkdir()
    wait_for(lambda: journal.health().pending_rows == 0)
    assert query(db, "SELECT outcome FROM casts") == [("completed",)]
    kept = query(db, "SELECT depth_m FROM samples ORDER BY id")
    assert kept == [(float(i),) for i in range(20 - len(kept), 20)]  # the newest ones
    assert len(kept) == 20 - health.dropped_rows == health.pending_rows - 2


def test_a_cast_started_while_the_file_was_unreadable_never_overwrites_an_old_one(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    db = tmp_path / "j.db"
    first = make_journal(db)
    first.open()
    old = first.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
    first.end_cast(old, outcome="completed", reached_depth_m=1.0)
    first.close()
    db.rename(tmp_path / "aside.db")  # the file is missing when the next journal opens...
    (tmp_path / "j.db").mkdir()  # ...and cannot be created (a directory is in the way)
    second = make_journal(db)
    with capture_logs() as logs:
        second.open()
        new = second.start_cast(STATION, planned_depth_m=2, mode="stepped", plan={})
        second.record_sample(new, 2.0, "dwelling")
        second.end_cast(new, outcome="completed", reached_depth_m=2.0)
        wait_for(lambda: second.health().write_errors > 0)
        (tmp_path / "j.db").rmdir()
        (tmp_path / "aside.db").rename(db)
        wait_for(lambda: second.health().pending_rows == 0)
    assert new == old == 1  # the id was handed out before the file could be read
    assert query(db, "SELECT id, mode, reached_depth_m FROM casts ORDER BY id") == [
        (1, "continuous", 1.0),
        (2, "stepped", 2.0),
    ]
    assert query(db, "SELECT cast_id, depth_m FROM samples") == [(2, 2.0)]
    assert any(e.get("stored_as") == 2 for e in logs)
    assert second.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={}) == 3


def test_misuse_is_logged_and_stored_never_raised(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    db = tmp_path / "j.db"
    journal = make_journal(db)
    journal.open()
    with capture_logs() as logs:
        cast_id = journal.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
        journal.record_sample(cast_id, 0.5, "floating")
        journal.record_sample(99, 0.5, "descending")
        journal.end_cast(cast_id, outcome="exploded", reached_depth_m=0.5)
        journal.record_event("odd", value=object())
        journal.record_fix("not a message")  # type: ignore[arg-type]
    journal.close()
    assert query(db, "SELECT cast_id, phase FROM samples ORDER BY id") == [
        (cast_id, "floating"),
        (99, "descending"),
    ]
    assert query(db, "SELECT outcome FROM casts") == [("exploded",)]
    assert query(db, "SELECT kind FROM events") == [("odd",)]
    errors = [e["event"] for e in logs if e["log_level"] == "error"]
    assert len(errors) == 4
    assert "journal could not record a fix" in errors


def test_a_failing_clock_never_reaches_the_daemon(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    broken = False

    def wall() -> float:
        if broken:
            raise OSError("clock gone")
        return time.time()

    journal = make_journal(tmp_path / "j.db", wall=wall)
    journal.open()
    broken = True
    with capture_logs() as logs:
        journal.record_fix(FIX)
        cast_id = journal.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
        journal.record_sample(cast_id, 0.5, "descending")
        journal.end_cast(cast_id, outcome="completed", reached_depth_m=0.5)
        journal.record_event("port_lost")
    assert cast_id == 1
    assert len([e for e in logs if e["log_level"] == "error"]) == 5


def test_open_twice_is_a_bug_and_close_twice_is_harmless(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    journal = make_journal(tmp_path / "j.db")
    journal.open()
    with pytest.raises(RuntimeError):
        journal.open()
    journal.close()
    journal.close()
    with capture_logs() as logs:
        journal.record_fix(FIX)  # after close: logged, never raised
    assert [e["event"] for e in logs] == ["journal is closed; row not recorded"]
    with pytest.raises(ValueError, match="max_buffered_rows"):
        Journal(tmp_path / "x.db", max_buffered_rows=0)


def test_a_row_sqlite_refuses_is_set_aside_and_the_rest_written(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    circular: dict[str, object] = {}
    circular["self"] = circular
    with capture_logs() as logs, Journal(db) as journal:
        cast_id = journal.start_cast(STATION, planned_depth_m=2, mode="continuous", plan=circular)
        journal.record_sample(cast_id, 1.0, "descending")
        journal.record_sample(cast_id, float("nan"), "descending")  # NULL: NOT NULL fails
        journal.record_sample(cast_id, object(), "descending")  # type: ignore[arg-type]
        journal.record_sample(cast_id, 2.0, "descending")
        journal.end_cast(cast_id, outcome="completed", reached_depth_m=2.0)
        journal.end_cast(42, outcome="completed", reached_depth_m=2.0)
    health = journal.health()
    assert (health.rows_written, health.dropped_rows) == (5, 2)
    assert query(db, "SELECT depth_m FROM samples ORDER BY id") == [(1.0,), (2.0,)]
    ((plan,),) = query(db, "SELECT plan_json FROM casts")
    assert "unserialisable_plan" in json.loads(plan)
    events = [e["event"] for e in logs if e["log_level"] == "error"]
    assert events.count("journal: SQLite refused a row; it is dropped") == 2
    assert "journal: end of a cast that is not in the file" in events


def test_fixes_keep_the_mode_byte_and_the_decoded_autopilot_time(
    tmp_path: Path, make_journal: MakeJournal
) -> None:
    db = tmp_path / "journal.db"
    journal = make_journal(db)
    journal.open()
    journal.record_fix(FIX, ap_time_s=0x4800, ap_time_order="little")
    journal.record_fix(STATION._replace(mode=0), ap_time_s=73, ap_time_order="big")
    journal.record_fix(STATION)
    journal.close()
    assert query(
        db, "SELECT frame, measuring_mode, ap_time_s, ap_time_order FROM fixes ORDER BY id"
    ) == [("P-T", None, 0x4800, "little"), ("P-M", 0, 73, "big"), ("P-M", None, None, None)]


def test_by_default_the_journal_asks_the_kernel_as_the_status_does(
    tmp_path: Path, make_journal: MakeJournal, monkeypatch: pytest.MonkeyPatch
) -> None:
    import ctypes.util

    from cc_daemon.ground import clocksync

    expected = clocksync.clock_sync().synchronised is True
    # libc is found once per process, never again from the event loop.
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: pytest.fail("looked up again"))
    db = tmp_path / "j.db"
    journal = make_journal(db)
    journal.open()
    journal.record_fix(FIX)
    journal.close()
    assert query(db, "SELECT clock_synced FROM fixes") == [(int(expected),)]
