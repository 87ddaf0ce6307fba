"""`cc-daemon casts | export | plot`: what a scientist types, and what they get."""

from __future__ import annotations

import argparse
import csv
import io
import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cc_daemon.cli import data as datacli
from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock, SurveySummary, write_survey


@pytest.fixture(scope="module")
def survey(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SurveySummary]:
    db = tmp_path_factory.mktemp("survey") / "survey.db"
    clock = FakeClock()
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    summary = write_survey(journal, clock, duration_s=1800, cast_every_s=600)
    journal.close()
    return db, summary


def run(*argv: str) -> int:
    """Parse as `cc-daemon` would with our commands registered, and call the handler."""
    parser = argparse.ArgumentParser(prog="cc-daemon")
    datacli.add_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    result: int = args.handler(args)
    return result


def test_casts_lists_every_cast(
    survey: tuple[Path, SurveySummary], capsys: pytest.CaptureFixture[str]
) -> None:
    db, summary = survey
    assert run("casts", "--db", str(db)) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == [
        "id",
        "station",
        "start",
        "(UTC)",
        "lat",
        "lon",
        "water",
        "m",
        "conf",
        "%",
        "reached",
        "m",
        "samples",
        "outcome",
    ]
    rows = lines[1:-1]
    assert len(rows) == summary.casts
    assert lines[-1].startswith("* the clock was not synchronised")
    first = rows[0].split()
    assert first[:4] == ["1", "S1", "2024-06-01T08:00:00Z*", "40.4506308"]
    assert first[8:10] == ["0", "skipped-shallow"]
    with JournalReader(db) as reader:
        cast2 = reader.casts(cast_id=2)[0]
    second = rows[1].split()
    assert second[:2] == ["2", "S2"]
    assert second[5:9] == [
        f"{cast2.water_depth_m:.2f}",
        "100",
        f"{cast2.reached_depth_m:.2f}",
        str(cast2.samples),
    ]
    assert second[9] == "completed"


def test_casts_since_and_running_casts(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = tmp_path / "j.db"
    clock = FakeClock()
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    station = StartMeasuring(1, -37260579, 404506308, 0, 8000, 100)
    done = journal.start_cast(station, planned_depth_m=2, mode="continuous", plan={})
    journal.end_cast(done, outcome="aborted", reached_depth_m=1.0, reason="winch stalled")
    clock.advance(3600)
    journal.start_cast(station, planned_depth_m=2, mode="continuous", plan={})
    journal.close()
    assert run("casts", "--db", str(db)) == 0
    out = capsys.readouterr().out
    assert "aborted (winch stalled)" in out
    assert out.splitlines()[2].endswith("running")  # never ended, and nobody reopened the file
    assert run("casts", "--db", str(db), "--since", "2024-06-01T08:30:00Z") == 0
    assert len(capsys.readouterr().out.splitlines()) == 3  # header, one cast, footnote


def test_casts_marks_a_blind_cast_and_shows_no_sentinel_as_water(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cc_daemon.core.cast.plan import plan_cast
    from tests.castkit import settings

    db = tmp_path / "j.db"
    clock = FakeClock()
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    station = StartMeasuring(1, -37260579, 404506308, 0, 4294967295, 100)  # no reading
    plan = plan_cast(station, settings().cast, 20.0)
    described = plan.describe()
    cast = journal.start_cast(station, planned_depth_m=1.0, mode="continuous", plan=described)
    journal.end_cast(cast, outcome="completed", reached_depth_m=1.0, reason=None)
    journal.close()
    assert run("casts", "--db", str(db)) == 0
    row = capsys.readouterr().out.splitlines()[1]
    assert row.split()[5:7] == ["-", "100"]  # not 4294967.30 m of water
    assert row.endswith("completed [blind: sonar distance 4294967295 mm cannot be a bottom]")


def samples_csv(text: str) -> list[dict[str, str]]:
    """The rows of a samples CSV, after its `#` provenance line."""
    assert text.startswith("# winch_backend: ")
    return list(csv.DictReader(io.StringIO(text.split("\r\n", 1)[1])))


def test_export_samples_csv_to_stdout_and_telemetry_to_a_file(
    survey: tuple[Path, SurveySummary], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db, summary = survey
    assert run("export", "--db", str(db), "--format", "csv") == 0
    text = capsys.readouterr().out
    # The synthetic journal predates the winch being recorded: it says so.
    assert text.startswith("# winch_backend: unknown; simulated: unknown\r\n")
    rows = samples_csv(text)
    assert len(rows) == summary.samples
    assert {r["phase"] for r in rows} == {"soaking", "descending", "dwelling", "ascending"}

    out = tmp_path / "fixes.csv"
    assert (
        run("export", "--db", str(db), "--format", "csv", "--what", "telemetry", "-o", str(out))
        == 0
    )
    assert f"wrote {summary.fixes} rows of telemetry to {out}" in capsys.readouterr().err
    with out.open(newline="") as f:
        assert len(list(csv.DictReader(f))) == summary.fixes


def test_export_filters_by_cast_and_time(
    survey: tuple[Path, SurveySummary], capsys: pytest.CaptureFixture[str]
) -> None:
    db, _ = survey
    with JournalReader(db) as reader:
        cast2 = reader.casts(cast_id=2)[0]
        third_start = reader.casts(cast_id=3)[0].start_wall_s
    assert run("export", "--db", str(db), "--format", "csv", "--cast", "2") == 0
    rows = samples_csv(capsys.readouterr().out)
    assert {r["cast_id"] for r in rows} == {"2"}
    assert len(rows) == cast2.samples

    since = "2024-06-01T08:20:00Z"  # cast 3 starts at 08:20
    assert third_start == pytest.approx(1_717_230_000.0)
    assert run("export", "--db", str(db), "--format", "csv", "--since", since) == 0
    rows = samples_csv(capsys.readouterr().out)
    assert rows and {r["cast_id"] for r in rows} == {"3"}
    assert min(r["time_utc"] for r in rows) >= "2024-06-01T08:20:00.000Z"


def test_export_geojson_and_netcdf_files(
    survey: tuple[Path, SurveySummary], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db, summary = survey
    assert run("export", "--db", str(db), "--format", "geojson", "--cast", "2") == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["type"] == "FeatureCollection"
    assert [f["properties"]["cast_id"] for f in doc["features"][:1]] == [2]

    netCDF4 = pytest.importorskip("netCDF4")
    out = tmp_path / "casts.nc"
    assert run("export", "--db", str(db), "--format", "netcdf", "-o", str(out)) == 0
    assert f"wrote {summary.casts} casts, {summary.samples} samples" in capsys.readouterr().err
    with netCDF4.Dataset(out) as nc:
        assert nc.featureType == "profile"
        assert len(nc.dimensions["obs"]) == summary.samples


@pytest.mark.parametrize(
    ("argv", "status", "message"),
    [
        (["export", "--format", "netcdf"], 2, "--format netcdf needs -o FILE"),
        (
            ["export", "--format", "geojson", "--what", "samples"],
            2,
            "--what applies to --format csv",
        ),
        (["export", "--format", "csv", "--what", "events", "--cast", "2"], 2, "--cast does not"),
        (["export", "--format", "csv", "--cast", "99"], 1, "no cast 99 in"),
        (["plot", "--cast", "1", "-o", "x.png"], 1, "cast 1 has no depth samples"),
        (["plot", "--cast", "2", "--since", "2024-01-01", "-o", "x.png"], 2, "--since applies"),
        (["plot", "--survey", "-o", "x.jpg"], 2, "x.jpg: the extension says which format"),
    ],
)
def test_usage_and_data_errors_are_one_line_and_a_status(
    survey: tuple[Path, SurveySummary],
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    status: int,
    message: str,
) -> None:
    db, _ = survey
    assert run(*argv, "--db", str(db)) == status
    captured = capsys.readouterr()
    assert captured.out == ""
    reading, *rest = captured.err.splitlines()
    if status == 1:  # the arguments made sense: the journal was opened, and said so
        assert reading == f"reading {db}"
    else:
        rest = [reading, *rest]
    assert len(rest) == 1
    assert rest[0].startswith(f"cc-daemon {argv[0]}: ")
    assert message in rest[0]


def test_a_missing_journal_or_a_bad_time_is_reported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run("casts", "--db", str(tmp_path / "none.db")) == 1
    assert "no journal at" in capsys.readouterr().err
    assert not (tmp_path / "none.db").exists()  # reading never creates a journal
    with pytest.raises(SystemExit) as exc:
        run("export", "--format", "csv", "--since", "yesterday")
    assert exc.value.code == 2
    assert "'yesterday' is not an ISO 8601 time" in capsys.readouterr().err


def test_plot_writes_pngs_or_says_what_is_missing(
    survey: tuple[Path, SurveySummary],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    pytest.importorskip("matplotlib")
    db, _ = survey
    cast_png, survey_png = tmp_path / "cast.png", tmp_path / "survey.png"
    assert run("plot", "--db", str(db), "--cast", "2", "-o", str(cast_png)) == 0
    assert run("plot", "--db", str(db), "--survey", "-o", str(survey_png)) == 0
    for png in (cast_png, survey_png):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert png.stat().st_size > 10_000
    assert "plotted cast 2 to" in capsys.readouterr().err

    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert run("plot", "--db", str(db), "--survey", "-o", str(tmp_path / "no.png")) == 1
    err = capsys.readouterr().err
    assert "needs the optional package 'matplotlib'" in err
    assert f"{sys.executable} -m pip install 'matplotlib>=3.8'" in err
    assert "make extras" in err


def test_export_reads_a_journal_the_daemon_is_writing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = tmp_path / "live.db"
    journal = Journal(db)
    journal.open()
    try:
        for i in range(5):
            journal.record_fix(Telemetry(i, -37260579, 404506308, 0, 8000, 100))
        deadline = time.monotonic() + 60  # only a hang reaches it
        while journal.health().pending_rows and time.monotonic() < deadline:
            time.sleep(0.01)
        assert run("export", "--db", str(db), "--format", "csv", "--what", "telemetry") == 0
        assert len(capsys.readouterr().out.splitlines()) == 6
        journal.record_fix(Telemetry(9, -37260579, 404506308, 0, 8000, 100))
        station = StartMeasuring(9, -37260579, 404506308, 0, 8000, 100)
        journal.start_cast(station, planned_depth_m=1, mode="continuous", plan={})
        while journal.health().pending_rows and time.monotonic() < deadline:
            time.sleep(0.01)
        assert journal.health().writable  # the reader never got in the writer's way
    finally:
        journal.close()
    assert journal.health().rows_written == 7


def test_the_real_command_line(survey: tuple[Path, SurveySummary]) -> None:
    db, summary = survey
    casts = subprocess.run(
        [sys.executable, "-m", "cc_daemon", "casts", "--db", str(db)],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert casts.returncode == 0, casts.stderr
    assert len(casts.stdout.splitlines()) == summary.casts + 2
    export = subprocess.run(
        [sys.executable, "-m", "cc_daemon", "export", "--db", str(db), "--format", "geojson"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert export.returncode == 0, export.stderr
    assert json.loads(export.stdout)["type"] == "FeatureCollection"


def test_db_defaults_to_the_configured_or_the_systemd_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # no ./cc-daemon.toml yet
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "state"))
    parser = argparse.ArgumentParser(prog="cc-daemon")
    datacli.add_commands(parser.add_subparsers(dest="command"))
    commands = (["casts"], ["export", "--format", "csv"], ["plot", "--survey", "-o", "x"])
    for command in commands:
        assert (
            datacli.journal_path(parser.parse_args(command)) == tmp_path / "state" / "cc-daemon.db"
        )
    # The daemon's configuration file names the journal: the commands read that one.
    (tmp_path / "cc-daemon.toml").write_text('[store]\npath = "/data/survey.db"\n')
    for command in commands:
        assert datacli.journal_path(parser.parse_args(command)) == Path("/data/survey.db")
    # --db wins over both.
    args = parser.parse_args(["casts", "--db", str(tmp_path / "mine.db")])
    assert datacli.journal_path(args) == tmp_path / "mine.db"
    # A caller may fix the default outright.
    fixed = argparse.ArgumentParser(prog="cc-daemon")
    datacli.add_commands(fixed.add_subparsers(dest="command"), default_db=tmp_path / "c.db")
    assert datacli.journal_path(fixed.parse_args(["casts"])) == tmp_path / "c.db"


def test_beside_a_fresh_simulate_db_the_commands_read_it_and_say_so(
    survey: tuple[Path, SurveySummary],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(tmp_path)  # no configuration, no ./cc-daemon.db
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    monkeypatch.setattr(datacli, "SERVICE_JOURNAL", tmp_path / "no-service" / "cc-daemon.db")
    db, _ = survey
    assert run("casts") == 1  # nothing here yet: the error names the file it looked for
    assert capsys.readouterr().err.startswith("reading cc-daemon.db\n")
    (tmp_path / "simulate.db").write_bytes(db.read_bytes())  # what `make simulate` leaves
    assert run("casts", "--db", str(db)) == 0
    expected = capsys.readouterr().out
    assert run("casts") == 0
    captured = capsys.readouterr()
    assert captured.err == "reading simulate.db\n"
    assert captured.out == expected
    # The service's own journal, when this machine has one, is still the one read.
    service = tmp_path / "service" / "cc-daemon.db"
    service.parent.mkdir()
    service.write_bytes(db.read_bytes())
    monkeypatch.setattr(datacli, "SERVICE_JOURNAL", service)
    assert run("export", "--format", "csv", "--what", "telemetry", "-o", "t.csv") == 0
    assert capsys.readouterr().err.startswith(f"reading {service}\n")
    # So is ./cc-daemon.db, the daemon's default.
    monkeypatch.setattr(datacli, "SERVICE_JOURNAL", tmp_path / "no-service" / "cc-daemon.db")
    (tmp_path / "cc-daemon.db").write_bytes(db.read_bytes())
    assert run("casts") == 0
    assert capsys.readouterr().err == "reading cc-daemon.db\n"
