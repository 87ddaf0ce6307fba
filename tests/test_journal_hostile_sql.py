"""A stranger's journal as SQL: tables replaced by views, slow real tables, huge cells,
and values that cannot be true (issue 27).

Real journals made hostile with SQLite itself: a table renamed away and a view of
its name put in its place (a recursive one that never ends, a 12-way self-join),
an unindexed file whose survey query takes minutes, a 20 MB event detail or sonde
reading, a 2 MB phase in a sample, deep JSON, text and 1e308 in time columns, a
missing `fixes` table. Every command answers in seconds (a child process with a
deadline), in bounded memory (capped at 1.5 GiB), and says in one line what it
did not read; never a traceback, never a value that cannot be true shown as good.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import re
import shutil
import sqlite3
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.hostilekit import run_command, run_commands
from tests.journalkit import (
    HOSTILE_VALUES,
    endless_view,
    huge_text,
    self_join_view,
    sql,
    survey_journal,
)
from tests.test_journal_damaged import COMMANDS, check, run
from tests.test_sonde_export import make_journal as sonde_journal


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    db = tmp_path_factory.mktemp("source") / "survey.db"
    survey_journal(db, casts=3)
    return db


def every_command(db: Path, out: Path) -> list[list[str]]:
    """The 13 data commands of tests/test_journal_damaged.py, `surveys`, `recover`."""
    argvs = []
    for command in COMMANDS.values():
        argv = [a.replace("{out}", str(out)) for a in command]
        at = len(argv) if argv[0] == "sonde" else 1
        argvs.append([*argv[:at], "--db", str(db), *argv[at:]])
    return [
        *argvs,
        ["surveys", "--db", str(db)],
        ["recover", "--db", str(db), "-o", str(out / "new.db")],
    ]


VIEWS: dict[str, Callable[[Path], None]] = {
    "fixes-endless": lambda db: endless_view(db, "fixes"),
    "casts-endless": lambda db: endless_view(db, "casts"),
    "sessions-endless": lambda db: endless_view(db, "sessions"),
    "events-endless": lambda db: endless_view(db, "events"),
    "samples-12-way": lambda db: self_join_view(db, "samples"),
    "fixes-12-way": lambda db: self_join_view(db, "fixes"),
}


@pytest.mark.parametrize("form", sorted(VIEWS))
def test_a_table_replaced_by_a_view_is_never_run_by_any_reader(
    form: str, source: Path, tmp_path: Path
) -> None:
    db = tmp_path / "survey.db"
    shutil.copyfile(source, db)
    VIEWS[form](db)
    table = form.split("-", maxsplit=1)[0]
    answers = run_commands(*every_command(db, tmp_path))
    named = 0
    for argv, answer in zip(every_command(db, tmp_path), answers, strict=True):
        assert "Traceback" not in answer.stderr, (argv, answer.stderr)
        assert answer.code == 1, (argv, answer.code, answer.stderr)
        assert len(answer.said) == 1, (argv, answer.stderr)
        named += f"{table} is a view, not a table" in answer.said[0]
    assert named >= 10  # said by nearly all (plot --cast 2 of a view of casts: "no cast 2")
    recovered = answers[-1]
    assert f"table {table} is a view, not a table: nothing saved from it" in recovered.said[0]


def unindexed_survey(db: Path, sessions: int, fixes: int) -> None:
    """A real journal whose survey query scans every fix once per session: its indexes
    dropped, `sessions` sessions, `fixes` fixes in the last one."""
    survey_journal(db, casts=1)
    with contextlib.closing(sqlite3.connect(db, isolation_level=None)) as conn:
        conn.execute("DROP INDEX fixes_by_session")
        conn.execute("DROP INDEX fixes_by_wall")
        conn.execute("BEGIN")
        conn.executemany(
            "INSERT INTO sessions (boot_id, pid, software, opened_mono_s, opened_wall_s,"
            " clock_synced) VALUES ('b', ?, 'x', 0, 1.7e9, 0)",
            [(i,) for i in range(sessions)],
        )
        last = conn.execute("SELECT max(id) FROM sessions").fetchone()[0]
        conn.executemany(
            "INSERT INTO fixes (session_id, mono_s, wall_s, clock_synced, frame,"
            " ap_timestamp_s, lon_e7, lat_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct)"
            " VALUES (?, ?, 1.7e9, 0, 'T', 0, 0, 0, 0, 0, 0)",
            [(last, float(i)) for i in range(fixes)],
        )
        conn.execute("COMMIT")


def test_a_query_that_runs_past_its_time_bound_is_ended_in_one_line(tmp_path: Path) -> None:
    db = tmp_path / "survey.db"
    unindexed_survey(db, sessions=4000, fixes=60_000)  # minutes of scanning without the bound
    answer = run_command(
        "surveys", "--db", str(db), setup="import cc_daemon.store.guard as g; g.QUERY_S = 1.0"
    )
    line = answer.one_clear_line()
    assert "reading the surveys, a query ran past 1.0 s and was ended" in line


def test_a_value_over_the_cell_bound_is_never_loaded_and_said_once(
    source: Path, tmp_path: Path
) -> None:
    db = tmp_path / "survey.db"
    shutil.copyfile(source, db)
    huge_text(db, "events", "detail_json", 20_000_000, "id = 1")
    huge_text(db, "samples", "phase", 2_000_000, "id = 20")  # a sample of cast 2
    sql(db, "UPDATE fixes SET lat_e7 = zeroblob(5000000) WHERE id = 7")  # a blob, not text
    track = tmp_path / "track.csv"
    events, plot, telemetry = run_commands(
        ["export", "--db", str(db), "--format", "csv", "--what", "events"],
        ["plot", "--db", str(db), "--cast", "2", "-o", str(tmp_path / "c.png")],
        ["export", "--db", str(db), "--format", "csv", "--what", "telemetry", "-o", str(track)],
    )
    # Said once, for the whole file, by whichever command meets the first.
    said = "3 values over 1 MiB not read (fixes 1, samples 1, events 1)"
    assert said in events.one_clear_line()
    assert events.stdout_chars < 1000  # the header, the event, and the other as given
    rows = list(csv.DictReader(io.StringIO(events.stdout)))
    assert [r["kind"] for r in rows] == ["daemon_started", "daemon_stopped"]
    assert rows[0]["detail"] == '{"unreadable_detail": "None"}'
    assert said in plot.one_clear_line()
    assert (tmp_path / "c.png").stat().st_size > 0  # the other 36 samples plotted
    assert said in telemetry.one_clear_line()
    assert "1 unreadable fixes skipped" in telemetry.one_clear_line()
    assert track.read_text().count("\n") == 753  # the header and every fix but that one


def test_a_huge_sonde_reading_is_not_read_and_said(tmp_path: Path) -> None:
    db = tmp_path / "sonde.db"
    sonde_journal(db)
    huge_text(db, "sonde_samples", "values_json", 20_000_000, "id = 3")
    out = run_command("sonde", "export", "--format", "csv", "--db", str(db))
    line = out.one_clear_line()
    assert "1 value over 1 MiB not read (sonde_samples 1)" in line
    assert "1 unreadable sonde samples skipped" in line
    assert out.stdout_chars == 0  # `sonde export` gives no partial answer: one line


@pytest.fixture(scope="module")
def sound(tmp_path_factory: pytest.TempPathFactory, source: Path) -> dict[str, tuple[int, str]]:
    answers = {}
    for command in COMMANDS:
        code, stdout, _ = run(command, source, tmp_path_factory.mktemp("out"))
        if command == "snapshot":
            stdout = re.sub(r"; \d+ kB$", "", stdout.rstrip()) + "\n"
        answers[command] = (code, stdout)
    return answers


@pytest.mark.parametrize("form", sorted(HOSTILE_VALUES))
def test_values_that_cannot_be_true_end_in_one_line_never_a_traceback(
    form: str, source: Path, sound: dict[str, tuple[int, str]], tmp_path: Path
) -> None:
    db = tmp_path / "survey.db"
    shutil.copyfile(source, db)
    HOSTILE_VALUES[form](db)
    damaged = 0
    for command in COMMANDS:
        out = tmp_path / command
        out.mkdir()
        code, stdout, stderr = run(command, db, out)
        if command == "snapshot":  # a faithful copy of the file, whose size changed
            stdout = re.sub(r"; \d+ kB$", "", stdout.rstrip()) + "\n"
        check(command, (code, stdout, stderr), sound[command])
        damaged += code != 0
    assert damaged >= 1
    surveys = run_command("surveys", "--db", str(db))
    assert "Traceback" not in surveys.stderr and surveys.code in (0, 1)
    if form == "text-in-times":
        assert "1 unreadable surveys skipped" in surveys.one_clear_line()


def test_deep_json_in_a_sonde_reading_and_its_map_is_one_line(tmp_path: Path) -> None:
    db = tmp_path / "sonde.db"
    sonde_journal(db)
    deep = "[" * 50_000 + "]" * 50_000
    sql(
        db,
        f"UPDATE sonde_samples SET values_json = '{deep}' WHERE id = 2",
        f"UPDATE events SET detail_json = '{{\"parameters\": {deep}}}'"
        " WHERE kind = 'sonde_started'",
    )
    for argv in (
        ["sonde", "export", "--format", "csv"],
        ["sonde", "export", "--format", "geojson"],
    ):
        out = run_command(*argv, "--db", str(db))
        line = out.one_clear_line()
        assert "1 unreadable sonde samples skipped" in line
        assert "1 events with unreadable JSON" in line


def test_text_under_the_cell_bound_is_drawn_short_in_a_plot(source: Path, tmp_path: Path) -> None:
    # 900 kB: under the bound, but matplotlib laid a label that long out for minutes.
    db = tmp_path / "survey.db"
    shutil.copyfile(source, db)
    huge_text(db, "samples", "phase", 900_000, "id = 20")
    sql(db, "UPDATE casts SET outcome = '$\\frac{1}{2}$' || outcome WHERE id = 2")
    sonde = tmp_path / "sonde.db"
    sonde_journal(sonde)
    name = "x" * 900_000
    with contextlib.closing(sqlite3.connect(sonde, isolation_level=None)) as conn:
        detail = json.loads(
            conn.execute("SELECT detail_json FROM events WHERE kind = 'sonde_started'").fetchone()[
                0
            ]
        )
        detail["parameters"][1]["long_name"] = name
        conn.execute(
            "UPDATE events SET detail_json = ? WHERE kind = 'sonde_started'", (json.dumps(detail),)
        )
    cast, profiles = run_commands(
        ["plot", "--db", str(db), "--cast", "2", "-o", str(tmp_path / "c.png")],
        ["sonde", "plot", "--cast", "1", "--db", str(sonde), "-o", str(tmp_path / "p.png")],
    )
    assert (cast.code, profiles.code) == (0, 0), (cast.stderr, profiles.stderr)
    assert (tmp_path / "c.png").stat().st_size > 0
    assert (tmp_path / "p.png").stat().st_size > 0
