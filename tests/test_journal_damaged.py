"""Every data command on a damaged journal says what is wrong (issue 20).

Real journals damaged as storage damages them (`journalkit.DAMAGE`: dropped
tables, undecodable text, bytes in a JSON column, a garbled page, a truncated
file; a flipped byte in a `-wal` frame; single-sector wipes) are read by all 13
data commands. Each either answers exactly as on the sound journal (exit 0),
or answers with what it could read and says on stderr what it skipped, or
fails with one line naming the problem (exit 1): never a traceback, never a
silent partial answer.
"""

from __future__ import annotations

import contextlib
import io
import random
import shutil
from pathlib import Path

import pytest

from cc_daemon.cli.app import main
from tests.journalkit import DAMAGE, SECTOR, flip_wal_byte, survey_journal, wipe_sector

COMMANDS: dict[str, list[str]] = {
    "casts": ["casts"],
    "export-samples": ["export", "--format", "csv"],
    "export-telemetry": ["export", "--format", "csv", "--what", "telemetry"],
    "export-events": ["export", "--format", "csv", "--what", "events"],
    "export-geojson": ["export", "--format", "geojson"],
    "export-netcdf": ["export", "--format", "netcdf", "-o", "{out}/s.nc"],
    "plot-cast": ["plot", "--cast", "2", "-o", "{out}/c.png"],
    "plot-survey": ["plot", "--survey", "-o", "{out}/s.png"],
    "snapshot": ["snapshot", "{out}/copy.db"],
    "sonde-export-csv": ["sonde", "export", "--format", "csv"],
    "sonde-export-geojson": ["sonde", "export", "--format", "geojson"],
    "sonde-export-netcdf": ["sonde", "export", "--format", "netcdf", "-o", "{out}/p.nc"],
    "sonde-plot": ["sonde", "plot", "--cast", "2", "-o", "{out}/p.png"],
}


def run(command: str, db: Path, out: Path) -> tuple[int, str, str]:
    """The real command line, in-process: exit status, stdout, stderr."""
    argv = [a.replace("{out}", str(out)) for a in COMMANDS[command]]
    argv = (
        [*argv[:1], "--db", str(db), *argv[1:]] if argv[0] != "sonde" else [*argv, "--db", str(db)]
    )
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = int(exc.code or 0)
    text = stdout.getvalue().replace(str(db), "{db}").replace(str(out), "{out}")
    return code, text, stderr.getvalue()


@pytest.fixture(scope="module")
def sound(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, tuple[int, str]]]:
    """A real 17-cast journal, and what each command answers on it."""
    db = tmp_path_factory.mktemp("sound") / "survey.db"
    survey_journal(db)
    answers = {}
    for command in COMMANDS:
        out = tmp_path_factory.mktemp("out")
        code, stdout, _ = run(command, db, out)
        answers[command] = (code, stdout)
    return db, answers


def check(command: str, result: tuple[int, str, str], sound: tuple[int, str]) -> None:
    code, stdout, stderr = result
    assert "Traceback" not in stderr
    assert code in (0, 1, 2), (command, code, stderr)
    if code == 0:  # only the whole answer may be given as good
        assert sound == (0, stdout), (command, "a changed answer with exit 0", stderr)
    else:
        said = [line for line in stderr.splitlines() if line.startswith("cc-daemon ")]
        assert said, (command, stderr)


@pytest.mark.parametrize("form", sorted(DAMAGE))
def test_every_data_command_on_a_damaged_journal_says_what_is_wrong(
    form: str, sound: tuple[Path, dict[str, tuple[int, str]]], tmp_path: Path
) -> None:
    source, answers = sound
    db = tmp_path / "survey.db"
    shutil.copyfile(source, db)
    DAMAGE[form](db)
    damaged = 0
    for command in COMMANDS:
        out = tmp_path / command
        out.mkdir()
        result = run(command, db, out)
        check(command, result, answers[command])
        damaged += result[0] != 0
    assert damaged >= 1  # the damage is seen, by one command at least


def test_a_flipped_byte_in_a_wal_frame_is_no_silent_partial_answer(tmp_path: Path) -> None:
    db = tmp_path / "survey.db"
    survey_journal(db, keep_wal=True)  # most rows only in the -wal
    flip_wal_byte(db, frame=3)
    code, _, stderr = run("casts", db, tmp_path)
    assert code == 1
    assert "write-ahead log is damaged at frame 3" in stderr
    code, _, stderr = run("snapshot", db, tmp_path)
    assert code == 1
    assert "write-ahead log is damaged" in stderr
    for command in COMMANDS:
        out = tmp_path / command
        out.mkdir()
        result = run(command, db, out)
        assert "Traceback" not in result[2]
        assert result[0] == 1, (command, result[2])


def test_random_single_sector_wipes_never_give_a_traceback(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    # A smaller journal (5 casts) keeps 39 wipes, 3 per command, within seconds.
    source = tmp_path_factory.mktemp("small") / "survey.db"
    survey_journal(source, casts=5)
    answers = {c: run(c, source, tmp_path_factory.mktemp("o"))[:2] for c in COMMANDS}
    sectors = source.stat().st_size // SECTOR
    rng = random.Random(20)
    commands = list(COMMANDS) * 3
    for trial, command in enumerate(commands):
        work = tmp_path_factory.mktemp(f"w{trial}")
        db = work / "survey.db"
        shutil.copyfile(source, db)
        wipe_sector(db, rng.randrange(sectors))
        out = work / "out"
        out.mkdir()
        result = run(command, db, out)
        check(
            command, result, (answers[command][0], answers[command][1].replace(str(source), "{db}"))
        )


def test_a_journal_that_is_not_one_fails_in_one_line(tmp_path: Path) -> None:
    db = tmp_path / "survey.db"
    db.write_bytes(b"\0" * 8192)
    code, _, stderr = run("casts", db, tmp_path)
    assert code == 1
    assert len(stderr.strip().splitlines()) <= 2  # "reading ..." and the one line


def recover(db: Path, dest: Path) -> tuple[int, str, str]:
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(["recover", "--db", str(db), "-o", str(dest)])
    return code, stdout.getvalue(), stderr.getvalue()


def test_recover_saves_every_readable_row_of_a_garbled_page(
    sound: tuple[Path, dict[str, tuple[int, str]]], tmp_path: Path
) -> None:
    source, answers = sound
    db = tmp_path / "survey.db"
    shutil.copyfile(source, db)
    DAMAGE["garbled-page"](db)
    before = db.read_bytes()
    code, report, stderr = recover(db, tmp_path / "new.db")
    assert db.read_bytes() == before  # the damaged file is never written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new.db", "survey.db"]
    assert "casts                  17 rows  of 17" in report
    assert code == 1  # samples cannot be counted in the damaged file: it says so
    assert "samples: cannot tell how many rows were lost" in stderr
    # The new journal is a sound one: every command reads it as the original.
    code, stdout, _ = run("casts", tmp_path / "new.db", tmp_path)
    assert (code, stdout) == answers["casts"]
    code, stdout, _ = run("export-samples", tmp_path / "new.db", tmp_path)
    assert (code, stdout) == answers["export-samples"]


def test_recover_of_a_truncated_journal_says_what_was_lost(
    sound: tuple[Path, dict[str, tuple[int, str]]], tmp_path: Path
) -> None:
    source, _ = sound
    db = tmp_path / "survey.db"
    shutil.copyfile(source, db)
    DAMAGE["truncated"](db)
    code, report, stderr = recover(db, tmp_path / "new.db")
    assert code == 1
    assert "cc-daemon recover: lost or damaged:" in stderr
    assert "Traceback" not in stderr
    code, stdout, _ = run("casts", tmp_path / "new.db", tmp_path)
    assert code == 0
    saved = [line for line in stdout.splitlines() if line.strip()[:1].isdigit()]
    assert 0 < len(saved) <= 17
    assert report.startswith(f"recovered {db} into {tmp_path / 'new.db'}")


def test_recover_of_a_torn_wal_reports_the_frames_it_cannot_read(tmp_path: Path) -> None:
    db = tmp_path / "survey.db"
    survey_journal(db, keep_wal=True)
    flip_wal_byte(db, frame=3)
    code, _, stderr = recover(db, tmp_path / "new.db")
    assert code == 1
    assert "the write-ahead log is damaged at frame 3" in stderr
    assert (tmp_path / "new.db").exists()


def test_recover_never_overwrites(tmp_path: Path) -> None:
    db = tmp_path / "survey.db"
    survey_journal(db, casts=2)
    (tmp_path / "new.db").write_text("mine")
    code, _, stderr = recover(db, tmp_path / "new.db")
    assert code == 2
    assert "refusing to overwrite" in stderr
    assert (tmp_path / "new.db").read_text() == "mine"
    code, report, _ = recover(db, tmp_path / "other.db")
    assert code == 0
    assert report.endswith("nothing lost\n")
