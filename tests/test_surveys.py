"""A survey (one daemon run) is the unit of data: the data commands read the latest
unless told otherwise, `surveys` lists them, and two simulations sharing a journal
each judge only their own casts."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cc_daemon.cli.app import main
from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock
from tests.daemonkit import REPO


def _run(path: Path, clock: FakeClock, casts: int, *, lat_e7: int, simulated: bool) -> None:
    """One daemon run: its own session, `casts` stations, a fix before each."""
    journal = Journal(
        path,
        monotonic=clock.monotonic,
        wall=clock.wall,
        winch_backend="sim" if simulated else "gpio",
        simulated=simulated,
    )
    journal.open()
    for i in range(casts):  # stations 85 m apart
        station = StartMeasuring(i, -37260579 + 10000 * i, lat_e7, 0, 6000, 90)
        journal.record_fix(Telemetry(i, -37260579 + 10000 * i, lat_e7, 0, 6000, 90))
        cast_id = journal.start_cast(station, planned_depth_m=2.0, mode="continuous", plan={})
        journal.record_sample(cast_id, 1.0, "descending")
        journal.end_cast(cast_id, outcome="completed", reached_depth_m=2.0)
        clock.advance(600.0)
    journal.close()
    clock.advance(86_400.0)


@pytest.fixture
def two_surveys(tmp_path: Path) -> Path:
    db = tmp_path / "j.db"
    clock = FakeClock()
    _run(db, clock, 3, lat_e7=404506308, simulated=True)  # casts 1-3, survey 1
    # A start that failed: a session with nothing in it is no survey.
    failed = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
    failed.open()
    failed.close()
    _run(db, clock, 2, lat_e7=404606308, simulated=False)  # casts 4-5
    return db


def test_surveys_lists_each_run_with_what_it_holds(
    two_surveys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["surveys", "--db", str(two_surveys)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == [
        "survey", "start", "(UTC)", "end", "(UTC)", "stations", "castable", "measured", "fixes",
        "data",
    ]  # fmt: skip
    first, second = (line.split() for line in lines[1:])
    assert first[0] == "1" and first[3:7] == ["3", "3", "3", "3"]
    assert first[7:] == ["SIMULATED", "(sim)"]
    assert second[0] == "3" and second[3:7] == ["2", "2", "2", "2"]
    assert second[7:] == ["real", "(gpio)"]
    assert first[1] == "2024-06-01T08:00Z"


def test_the_data_commands_read_the_latest_survey_unless_told(
    two_surveys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def ids(*extra: str) -> list[int]:
        assert main(["casts", "--db", str(two_surveys), *extra]) == 0
        rows = capsys.readouterr().out.splitlines()[1:]
        return [int(row.split()[0]) for row in rows if row.split()[0].isdigit()]

    assert main(["casts", "--db", str(two_surveys)]) == 0
    out, err = capsys.readouterr()
    assert [row.split()[0] for row in out.splitlines()[1:3]] == ["4", "5"]
    assert "survey 3, the latest of 2" in err and "--survey all" in err
    assert ids("--survey", "1") == [1, 2, 3]
    assert ids("--survey", "all") == [1, 2, 3, 4, 5]


def test_a_survey_that_does_not_exist_or_cannot_be_one_is_said_in_one_line(
    two_surveys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["casts", "--db", str(two_surveys), "--survey", "2"]) == 1
    assert capsys.readouterr().err.strip().endswith("(surveys: 1, 3)")
    with pytest.raises(SystemExit) as exit_:
        main(["casts", "--db", str(two_surveys), "--survey", "lastest"])
    assert exit_.value.code == 2
    assert "a survey's number, 'all' or 'latest'" in capsys.readouterr().err


def test_exports_and_plots_take_the_survey_and_a_cast_from_any(
    two_surveys: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = str(two_surveys)
    assert main(["export", "--db", db, "--format", "csv", "--what", "telemetry"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 1 + 2
    assert main(["export", "--db", db, "--format", "csv", "--survey", "all"]) == 0
    assert {row.split(",")[0] for row in capsys.readouterr().out.splitlines()[2:]} == {
        "1", "2", "3", "4", "5",
    }  # fmt: skip
    # A cast's number is unique in the file: found whatever the latest survey is.
    assert main(["export", "--db", db, "--format", "csv", "--cast", "2"]) == 0
    assert [r.split(",")[0] for r in capsys.readouterr().out.splitlines()[2:]] == ["2"]
    pytest.importorskip("matplotlib")
    assert main(["plot", "--db", db, "--survey", "1", "-o", str(tmp_path / "s1.png")]) == 0
    assert "the survey (3 fixes, 3 casts)" in capsys.readouterr().err
    assert main(["plot", "--db", db, "--survey", "-o", str(tmp_path / "s3.png")]) == 0
    assert "the survey (2 fixes, 2 casts)" in capsys.readouterr().err


def test_the_reader_narrows_every_table_to_its_survey(two_surveys: Path) -> None:
    with JournalReader(two_surveys, survey=1) as reader:
        assert [c.id for c in reader.casts()] == [1, 2, 3]
        assert {s.cast_id for s in reader.samples()} == {1, 2, 3}
        assert {f.session_id for f in reader.fixes()} == {1}
        assert {e.session_id for e in reader.events()} <= {1}


@pytest.mark.slow
def test_two_simulations_in_one_directory_each_judge_only_their_own(tmp_path: Path) -> None:
    env = {**os.environ, "CC_DAEMON_CAST__TARGET_DEPTH_M": "2.0", "PYTHONPATH": str(REPO)}
    command = [sys.executable, "-m", "cc_daemon", "--simulate", "--stations", "1", "--plain"]
    runs = [
        subprocess.Popen(
            [*command, "--db", str(tmp_path / "shared.db")],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
            cwd=tmp_path,
            text=True,
        )
        for _ in range(2)
    ]
    outputs = [run.communicate(timeout=120) for run in runs]
    for run, (out, err) in zip(runs, outputs, strict=True):
        assert run.returncode == 0, out + err
        assert "FAILED" not in out and "PROTOCOL VIOLATED" not in out, out
    with JournalReader(tmp_path / "shared.db") as reader:
        surveys = reader.surveys()
    assert len(surveys) == 2 and all(s.stations == 1 for s in surveys)
    # Each daemon had its own status and control sockets: no task fought over one.
    log = (tmp_path / "shared.log").read_text()
    assert "crashed" not in log and "socket unavailable" not in log
