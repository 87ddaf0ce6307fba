"""Sonde readings in a real SQLite journal: stored whole, missing values as NULL with reasons."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from cc_daemon.core.protocol import StartMeasuring
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.schema import MIGRATIONS, SCHEMA_VERSION
from cc_daemon.store.sonde import MIGRATION

STATION = StartMeasuring(100, -37000000, 404000000, 0, 6000, 90)


def test_readings_round_trip_with_missing_values(tmp_path: Path) -> None:
    path = tmp_path / "j.db"
    journal = Journal(path)
    journal.open()
    cast_id = journal.start_cast(STATION, planned_depth_m=5.0, mode="continuous", plan={})
    journal.record_sonde_sample(
        cast_id=cast_id,
        phase="descending",
        mono_s=10.0,
        wall_s=1_700_000_000.0,
        duration_s=0.08,
        status="partial",
        error=None,
        line_out_m=2.5,
        sonde_depth_m=2.47,
        values={"depth": 2.47, "temperature": 21.5, "ph": None, "chlorophyll": float("nan")},
        missing={"ph": "nan", "chlorophyll": "nan"},
        simulated=True,
    )
    journal.record_sonde_sample(
        cast_id=None,
        phase="surface",
        mono_s=30.0,
        wall_s=1_700_000_020.0,
        duration_s=0.6,
        status="timeout",
        error="no reply in 0.3 s",
        line_out_m=0.0,
        sonde_depth_m=None,
        values={"depth": None, "temperature": None},
        missing={"depth": "timeout", "temperature": "timeout"},
        simulated=False,
    )
    journal.close()
    with JournalReader(path) as reader:
        first, second = reader.sonde_samples()
        assert reader.sonde_samples(cast_id=cast_id) == [first]
    assert first.cast_id == cast_id and first.phase == "descending"
    assert first.values == {"depth": 2.47, "temperature": 21.5, "ph": None, "chlorophyll": None}
    assert first.missing == {"chlorophyll": "nan", "ph": "nan"}
    assert first.line_out_m == 2.5 and first.sonde_depth_m == 2.47 and first.simulated
    assert second.cast_id is None and second.status == "timeout"
    assert second.values == {"depth": None, "temperature": None}  # never 0.0
    with sqlite3.connect(path) as conn:
        (raw,) = conn.execute("SELECT values_json FROM sonde_samples WHERE id = 2").fetchone()
    assert raw == '{"depth":null,"temperature":null}'


def test_migration_is_one_self_contained_step() -> None:
    assert MIGRATION in MIGRATIONS
    assert len(MIGRATIONS) == SCHEMA_VERSION
    conn = sqlite3.connect(":memory:")
    for step in MIGRATIONS:
        for statement in step:
            conn.execute(statement)
    columns = [r[1] for r in conn.execute("PRAGMA table_info(sonde_samples)")]
    assert "values_json" in columns and "missing_json" in columns and "line_out_m" in columns
