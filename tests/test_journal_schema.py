"""A newer daemon opens a journal written by the first schema, and readers never migrate."""

from __future__ import annotations

import contextlib
import sqlite3
from pathlib import Path

import pytest

from cc_daemon.core.protocol import StartMeasuring
from cc_daemon.store import SCHEMA_VERSION, Journal, JournalReader, StoreError
from cc_daemon.store.schema import APPLICATION_ID

# The first schema, frozen here as the first release wrote it: the test must
# keep passing against this text even if schema.py is ever edited by mistake.
V1_DDL = f"""
CREATE TABLE fixes (
    id INTEGER PRIMARY KEY, mono_s REAL NOT NULL, wall_s REAL NOT NULL,
    clock_synced INTEGER NOT NULL, frame TEXT NOT NULL, ap_timestamp_s INTEGER NOT NULL,
    lon_e7 INTEGER NOT NULL, lat_e7 INTEGER NOT NULL, alt_mm INTEGER NOT NULL,
    sonar_distance_mm INTEGER NOT NULL, sonar_confidence_pct INTEGER NOT NULL);
CREATE TABLE casts (
    id INTEGER PRIMARY KEY, start_mono_s REAL NOT NULL, start_wall_s REAL NOT NULL,
    start_clock_synced INTEGER NOT NULL, ap_timestamp_s INTEGER NOT NULL,
    lon_e7 INTEGER NOT NULL, lat_e7 INTEGER NOT NULL, alt_mm INTEGER NOT NULL,
    sonar_distance_mm INTEGER NOT NULL, sonar_confidence_pct INTEGER NOT NULL,
    planned_depth_m REAL NOT NULL, mode TEXT NOT NULL, plan_json TEXT NOT NULL,
    end_mono_s REAL, end_wall_s REAL, end_clock_synced INTEGER, outcome TEXT,
    reached_depth_m REAL, reason TEXT);
CREATE TABLE samples (
    id INTEGER PRIMARY KEY, cast_id INTEGER NOT NULL REFERENCES casts(id),
    mono_s REAL NOT NULL, wall_s REAL NOT NULL, clock_synced INTEGER NOT NULL,
    depth_m REAL NOT NULL, phase TEXT NOT NULL);
CREATE INDEX samples_by_cast ON samples(cast_id, mono_s);
CREATE TABLE events (
    id INTEGER PRIMARY KEY, mono_s REAL NOT NULL, wall_s REAL NOT NULL,
    clock_synced INTEGER NOT NULL, kind TEXT NOT NULL, detail_json TEXT NOT NULL);
PRAGMA application_id = {APPLICATION_ID};
PRAGMA user_version = 1;
INSERT INTO fixes VALUES (1, 10.0, 1700000000.0, 1, 'P-T', 5, -37260579, 404506308, 702385,
    8219, 100);
INSERT INTO casts VALUES (1, 11.0, 1700000001.0, 1, 6, -37260579, 404506308, 702385, 8219, 100,
    5.0, 'continuous', '{{"target_depth_m": 5.0}}', 80.0, 1700000070.0, 1, 'completed', 5.0, NULL);
INSERT INTO casts VALUES (2, 100.0, 1700000090.0, 1, 95, -37260000, 404506000, 702385, 4000, 90,
    3.5, 'stepped', '{{}}', NULL, NULL, NULL, NULL, NULL, NULL);
INSERT INTO samples VALUES (1, 1, 12.0, 1700000002.0, 1, 0.25, 'descending');
INSERT INTO samples VALUES (2, 2, 101.0, 1700000091.0, 1, 0.5, 'descending');
INSERT INTO samples VALUES (3, 2, 102.0, 1700000092.0, 1, 0.75, 'descending');
INSERT INTO events VALUES (1, 9.0, 1699999999.0, 1, 'daemon_started', '{{}}');
"""

STATION = StartMeasuring(73, -37260600, 404506400, 702000, 6500, 90)


def write_v1(path: Path) -> None:
    with contextlib.closing(sqlite3.connect(path)) as conn:
        conn.executescript(V1_DDL)
        conn.commit()


def layout(path: Path) -> dict[str, list[tuple[object, ...]]]:
    """Every table's columns and every index, as SQLite reports them."""
    with contextlib.closing(sqlite3.connect(path)) as conn:
        tables = [r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")]
        shape = {t: conn.execute(f"PRAGMA table_info({t})").fetchall() for t in sorted(tables)}
        shape["indexes"] = sorted(
            conn.execute("SELECT name, tbl_name FROM sqlite_master WHERE type='index'").fetchall()
        )
        shape["pragmas"] = [
            conn.execute("PRAGMA user_version").fetchone(),
            conn.execute("PRAGMA application_id").fetchone(),
        ]
    return shape


def test_a_v1_file_is_migrated_and_its_crashed_cast_closed(tmp_path: Path) -> None:
    db = tmp_path / "old.db"
    write_v1(db)
    journal = Journal(db)
    try:
        assert journal.open() == [2]
        new = journal.start_cast(STATION, planned_depth_m=2.0, mode="continuous", plan={})
        journal.record_sample(new, 1.0, "descending")
        journal.end_cast(new, outcome="completed", reached_depth_m=1.0)
    finally:
        journal.close()
    assert new == 3

    with contextlib.closing(sqlite3.connect(db)) as conn:
        assert conn.execute("PRAGMA user_version").fetchone() == (SCHEMA_VERSION,)
        assert conn.execute("SELECT id, session_id FROM casts ORDER BY id").fetchall() == [
            (1, None),  # written before sessions existed: boot unknown
            (2, None),
            (3, 1),
        ]
    with JournalReader(db) as reader:
        casts = reader.casts()
        assert [(c.id, c.outcome, c.reached_depth_m) for c in casts] == [
            (1, "completed", 5.0),
            (2, "unfinished", 0.75),
            (3, "completed", 1.0),
        ]
        assert casts[0].plan == {"target_depth_m": 5.0}
        assert casts[1].end_wall_s == 1700000092.0  # the last sample: when the data ends
        assert [s.depth_m for s in reader.samples(cast_id=2)] == [0.5, 0.75]
        assert len(reader.fixes()) == 1
        assert [e.kind for e in reader.events()] == ["daemon_started"]


def test_a_new_file_and_a_migrated_v1_file_have_the_same_layout(tmp_path: Path) -> None:
    old, fresh = tmp_path / "old.db", tmp_path / "fresh.db"
    write_v1(old)
    for path in (old, fresh):
        journal = Journal(path)
        journal.open()
        journal.close()
    assert layout(old) == layout(fresh)
    assert layout(fresh)["pragmas"] == [(SCHEMA_VERSION,), (APPLICATION_ID,)]


def test_the_reader_reads_a_v1_file_without_changing_it(tmp_path: Path) -> None:
    db = tmp_path / "old.db"
    write_v1(db)
    before = db.read_bytes()
    with JournalReader(db) as reader:
        assert [c.outcome for c in reader.casts()] == ["completed", None]  # not its call to mark
        assert reader.fixes()[0].session_id is None
    assert db.read_bytes() == before


def test_the_reader_refuses_what_it_cannot_read(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="no journal at"):
        JournalReader(tmp_path / "missing.db")
    newer = tmp_path / "newer.db"
    with contextlib.closing(sqlite3.connect(newer)) as conn:
        conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
        conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
        conn.commit()
    with pytest.raises(StoreError, match="newer cc-daemon"):
        JournalReader(newer)
    garbage = tmp_path / "garbage.db"
    garbage.write_bytes(b"not sqlite" * 100)
    with pytest.raises(StoreError, match=r"garbage\.db"):
        JournalReader(garbage)
