"""The daemon's own sonar readings in the exports: CSV (`--what sonar`) and the NetCDF.

Readings are exported as they arrived, with the same validity flag the planner
uses: a confidence of 150 stays 150, flagged invalid.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import pytest

from cc_daemon.export import csv as csv_export
from cc_daemon.export import netcdf
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock, write_survey
from tests.test_datacli import run

READINGS = [(3012, 97), (3020, 150), (4294967295, 100), (3031, 88)]


@pytest.fixture(scope="module")
def journal_with_sonar(tmp_path_factory: pytest.TempPathFactory) -> Path:
    db = tmp_path_factory.mktemp("sonar") / "j.db"
    clock = FakeClock()
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    write_survey(journal, clock, duration_s=700, cast_every_s=600)  # two casts
    for mm, conf in READINGS:  # between the second cast and the third
        clock.advance(0.25)
        journal.record_sonar("/dev/ttyPING", mm, conf)
    write_survey(journal, clock, duration_s=10, cast_every_s=600)  # a third cast
    journal.close()
    return db


def test_sonar_csv_holds_every_reading_as_it_arrived(
    journal_with_sonar: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run("export", "--db", str(journal_with_sonar), "--format", "csv",
               "--what", "sonar") == 0  # fmt: skip
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert tuple(rows[0]) == csv_export.SONAR_COLUMNS
    assert [(r["distance_m"], r["confidence_pct"], r["valid"]) for r in rows] == [
        ("3.012", "97", "1"), ("3.020", "150", "0"), ("4294967.295", "100", "0"),
        ("3.031", "88", "1"),
    ]  # fmt: skip
    assert all(r["time_utc"].endswith("Z") and r["port"] == "/dev/ttyPING" for r in rows)
    assert run("export", "--db", str(journal_with_sonar), "--format", "csv", "--what",
               "sonar", "--cast", "1") == 2  # fmt: skip


def test_sonar_readings_ride_with_the_netcdf_profiles(
    journal_with_sonar: Path, tmp_path: Path
) -> None:
    netCDF4 = pytest.importorskip("netCDF4")
    path = tmp_path / "casts.nc"
    assert run("export", "--db", str(journal_with_sonar), "--format", "netcdf",
               "-o", str(path)) == 0  # fmt: skip
    with JournalReader(journal_with_sonar) as reader:
        expected = reader.sonar_readings()
    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        assert len(nc.dimensions["sonar_obs"]) == len(READINGS) == len(expected)
        assert list(nc["sonar_distance"][:]) == [mm / 1000 for mm, _ in READINGS]
        assert list(nc["sonar_reading_confidence"][:]) == [c for _, c in READINGS]
        assert list(nc["sonar_valid"][:]) == [1, 0, 0, 1]
        assert list(nc["sonar_time"][:]) == [round(r.wall_s, 3) for r in expected]
        assert nc["sonar_time"].standard_name == "time"
    # A cast's own export holds only the readings within it: none here.
    one = tmp_path / "one.nc"
    assert run("export", "--db", str(journal_with_sonar), "--format", "netcdf",
               "--cast", "1", "-o", str(one)) == 0  # fmt: skip
    with netCDF4.Dataset(one) as nc:
        assert "sonar_obs" not in nc.dimensions


def test_the_netcdf_with_sonar_passes_the_cf_checker(
    journal_with_sonar: Path, tmp_path: Path
) -> None:
    pytest.importorskip("netCDF4")
    from tests.test_export import _cf_problems

    path = tmp_path / "casts.nc"
    with JournalReader(journal_with_sonar) as reader:
        casts = reader.casts()
        sonar = netcdf.sonar_during(casts, reader.sonar_readings)
        netcdf.write(casts, reader.samples(), path, sonar=sonar)
    assert len(sonar) == len(READINGS)
    assert _cf_problems(path, tmp_path) == []
