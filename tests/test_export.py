"""Exports parse in the formats' own terms: csv, RFC 7946 GeoJSON, CF profile NetCDF."""

from __future__ import annotations

import csv
import io
import json
import math
import sys
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import pytest

from cc_daemon.export import OptionalDependencyError, geojson, netcdf
from cc_daemon.export import csv as csv_export
from cc_daemon.store import PHASES, Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock, SurveySummary, write_survey


@pytest.fixture(scope="module")
def survey(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SurveySummary]:
    """An hour of survey: 3,600 fixes and a cast every ten minutes, the first skipped."""
    db = tmp_path_factory.mktemp("survey") / "j.db"
    clock = FakeClock()
    journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    summary = write_survey(journal, clock, duration_s=3600, cast_every_s=600)
    journal.close()
    assert journal.health().dropped_rows == 0
    return db, summary


def parse_utc(text: str) -> datetime:
    assert text.endswith("Z"), text
    stamp = datetime.fromisoformat(text)
    assert stamp.utcoffset() == timedelta(0)
    return stamp


def test_samples_csv_has_one_row_per_sample(survey: tuple[Path, SurveySummary]) -> None:
    db, summary = survey
    out = io.StringIO()
    with JournalReader(db) as reader:
        records = reader.samples()
        casts = {c.id: c for c in reader.casts()}
    assert csv_export.write_samples(records, out) == summary.samples
    rows = list(csv.DictReader(io.StringIO(out.getvalue())))
    assert list(rows[0]) == list(csv_export.SAMPLE_COLUMNS)
    assert len(rows) == summary.samples
    for row, record in zip(rows, records, strict=True):
        cast = casts[int(row["cast_id"])]
        assert parse_utc(row["time_utc"]).timestamp() == pytest.approx(record.wall_s, abs=1e-3)
        assert float(row["lat"]) == pytest.approx(cast.lat_deg, abs=1e-7)
        assert float(row["lon"]) == pytest.approx(cast.lon_deg, abs=1e-7)
        assert 0.0 <= float(row["depth_m"]) <= cast.planned_depth_m
        assert row["phase"] in PHASES
        assert row["clock_synced"] == "0"
    by_cast: dict[str, list[float]] = {}
    for row in rows:
        by_cast.setdefault(row["cast_id"], []).append(float(row["monotonic_s"]))
    assert all(times == sorted(times) for times in by_cast.values())
    assert len(by_cast) == summary.casts - summary.skipped


def test_telemetry_csv_has_one_row_per_fix(survey: tuple[Path, SurveySummary]) -> None:
    db, summary = survey
    out = io.StringIO()
    with JournalReader(db) as reader:
        fixes = reader.fixes()
    csv_export.write_fixes(fixes, out)
    rows = list(csv.DictReader(io.StringIO(out.getvalue())))
    assert len(rows) == summary.fixes
    assert sum(row["frame"] == "P-M" for row in rows) == summary.casts
    first = rows[0]
    assert first["time_utc"] == "2024-06-01T08:00:00.000Z"
    assert (float(first["lat"]), float(first["lon"])) == (40.4506308, -3.7260579)
    assert float(first["sonar_depth_m"]) == pytest.approx(fixes[0].sonar_distance_m)
    assert float(first["alt_m"]) == 702.385


def test_events_csv_holds_json_details(survey: tuple[Path, SurveySummary]) -> None:
    db, summary = survey
    out = io.StringIO()
    with JournalReader(db) as reader:
        assert csv_export.write_events(reader.events(), out) == summary.events
    rows = list(csv.DictReader(io.StringIO(out.getvalue())))
    assert [r["kind"] for r in rows] == ["daemon_started", "daemon_stopped"]
    assert json.loads(rows[0]["detail"]) == {"version": "synthetic"}


def check_rfc7946(doc: Any) -> None:
    """The structure RFC 7946 requires of what we write (and QGIS relies on)."""
    assert doc["type"] == "FeatureCollection"
    assert "crs" not in doc  # RFC 7946 4: WGS 84 only, no crs member
    assert isinstance(doc["features"], list)

    def position(p: Any) -> None:
        assert isinstance(p, list) and len(p) == 2
        lon, lat = p
        assert all(isinstance(v, float | int) and math.isfinite(v) for v in p)
        assert -180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0

    for feature in doc["features"]:
        assert feature["type"] == "Feature"
        assert isinstance(feature["properties"], dict)
        if "id" in feature:
            assert isinstance(feature["id"], str | int)
        geometry = feature["geometry"]
        if geometry["type"] == "Point":
            position(geometry["coordinates"])
        elif geometry["type"] == "LineString":
            assert len(geometry["coordinates"]) >= 2
            for p in geometry["coordinates"]:
                position(p)
        else:
            pytest.fail(f"unexpected geometry {geometry['type']}")


def test_geojson_is_a_valid_feature_collection_of_the_survey(
    survey: tuple[Path, SurveySummary],
) -> None:
    db, summary = survey
    out = io.StringIO()
    with JournalReader(db) as reader:
        casts, fixes = reader.casts(), reader.fixes()
    count = geojson.write(casts, fixes, out)
    doc = json.loads(out.getvalue())
    check_rfc7946(doc)
    assert count == len(doc["features"]) == summary.casts + 1 + summary.fixes
    kinds = [f["properties"]["feature"] for f in doc["features"]]
    assert kinds.count("station") == summary.casts
    assert kinds.count("track") == 1
    assert kinds.count("sounding") == summary.fixes

    stations = [f for f in doc["features"] if f["properties"]["feature"] == "station"]
    first = stations[0]
    assert first["geometry"]["coordinates"] == [casts[0].lon_deg, casts[0].lat_deg]  # [lon, lat]
    props = first["properties"]
    assert props["outcome"] == "skipped-shallow"
    assert props["samples"] == 0
    assert props["water_depth_m"] == casts[0].water_depth_m
    parse_utc(props["start_utc"])
    completed = stations[1]["properties"]
    assert completed["outcome"] == "completed"
    assert completed["reached_depth_m"] == pytest.approx(completed["planned_depth_m"])

    (track,) = [f for f in doc["features"] if f["properties"]["feature"] == "track"]
    assert len(track["geometry"]["coordinates"]) == summary.fixes
    sounding = next(f for f in doc["features"] if f["properties"]["feature"] == "sounding")
    assert set(sounding["properties"]) >= {"depth_m", "confidence_pct", "time_utc"}


def test_geojson_of_one_cast_has_the_track_while_it_ran(
    survey: tuple[Path, SurveySummary],
) -> None:
    db, _ = survey
    with JournalReader(db) as reader:
        casts = reader.casts(cast_id=2)
        fixes = reader.fixes(cast_id=2)
    doc = geojson.feature_collection(casts, fixes)
    check_rfc7946(doc)
    (track,) = [f for f in doc["features"] if f["properties"]["feature"] == "track"]
    station = doc["features"][0]["geometry"]["coordinates"]
    # The boat holds the station during the cast: every fix is where the cast is.
    assert {tuple(p) for p in track["geometry"]["coordinates"]} == {tuple(station)}
    assert len(fixes) == casts[0].samples + 1  # one a second, plus the `M` frame


def test_geojson_without_a_track_has_no_degenerate_line() -> None:
    doc = geojson.feature_collection([], [])
    check_rfc7946(doc)
    assert doc["features"] == []


def test_netcdf_follows_the_cf_profile_conventions(
    survey: tuple[Path, SurveySummary], tmp_path: Path
) -> None:
    netCDF4 = pytest.importorskip("netCDF4")
    db, summary = survey
    path = tmp_path / "casts.nc"
    with JournalReader(db) as reader:
        casts, samples = reader.casts(), reader.samples()
    assert netcdf.write(casts, samples, path) == summary.samples
    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        assert nc.featureType == "profile"
        assert nc.Conventions.startswith("CF-")
        assert nc.data_model == "NETCDF4_CLASSIC"
        assert len(nc.dimensions["profile"]) == summary.casts
        assert len(nc.dimensions["obs"]) == summary.samples
        assert nc["profile"].cf_role == "profile_id"
        assert nc["row_size"].sample_dimension == "obs"
        assert nc["time"].units == "seconds since 1970-01-01 00:00:00 UTC"
        assert nc["lat"].standard_name == "latitude" and nc["lon"].units == "degrees_east"
        assert nc["depth"].positive == "down" and nc["depth"].axis == "Z"
        assert nc["phase"].coordinates == "obs_time lat lon depth"
        assert nc["obs_time"].standard_name == "time"
        assert list(nc["profile"][:]) == [c.id for c in casts]
        assert list(nc["time"][:]) == [round(c.start_wall_s, 3) for c in casts]
        assert list(nc["lat"][:]) == [round(c.lat_deg, 7) for c in casts]
        row_size = list(nc["row_size"][:])
        assert row_size == [c.samples for c in casts]
        outcomes = nc["outcome"].flag_meanings.split()
        assert outcomes[nc["outcome"][0]] == "skipped_shallow"

        phases = nc["phase"].flag_meanings.split()
        depth, phase = nc["depth"][:], nc["phase"][:]
        start = 0
        for cast, size in zip(casts, row_size, strict=True):
            mine = [s for s in samples if s.cast_id == cast.id]
            assert list(depth[start : start + size]) == [round(s.depth_m, 3) for s in mine]
            assert [phases[p] for p in phase[start : start + size]] == [s.phase for s in mine]
            start += size
        assert list(nc["reached_depth"][:]) == pytest.approx([c.reached_depth_m for c in casts])


def test_netcdf_needs_its_extra_and_a_cast(
    survey: tuple[Path, SurveySummary], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(ValueError, match="no casts"):
        netcdf.write([], [], tmp_path / "empty.nc")
    monkeypatch.setitem(sys.modules, "netCDF4", None)  # import netCDF4 now fails
    with pytest.raises(OptionalDependencyError, match=r"-m pip install 'netCDF4>=1.6'"):
        netcdf.write([], [], tmp_path / "x.nc")
    assert not (tmp_path / "x.nc").exists()


def _cf_problems(path: Path, tmp_path: Path) -> list[str]:
    """What the IOOS compliance checker's CF 1.8 suite says about `path`, strictly:
    every message of every priority (an empty list is a clean file)."""
    runner = pytest.importorskip("compliance_checker.runner")
    runner.CheckSuite().load_all_available_checkers()
    report = tmp_path / f"{path.stem}-cf.json"
    passed, errors = runner.ComplianceChecker.run_checker(
        str(path), ["cf:1.8"], 0, "strict", output_filename=str(report), output_format="json"
    )
    assert not errors
    (result,) = json.loads(report.read_text()).values()
    problems = [f"{c['name']}: {m}" for c in result["all_priorities"] for m in c["msgs"]]
    assert passed == (not problems) or problems
    if result["scored_points"] != result["possible_points"]:
        problems.append(f"scored {result['scored_points']} of {result['possible_points']}")
    return problems


def test_netcdf_passes_the_cf_checker_and_a_spoiled_file_does_not(
    survey: tuple[Path, SurveySummary], tmp_path: Path
) -> None:
    netCDF4 = pytest.importorskip("netCDF4")
    db, _ = survey
    path = tmp_path / "casts.nc"
    with JournalReader(db) as reader:
        netcdf.write(reader.casts(), reader.samples(), path)
    assert _cf_problems(path, tmp_path) == []
    # The checker is not a rubber stamp: the same file with a unit CF cannot parse fails.
    spoiled = tmp_path / "spoiled.nc"
    spoiled.write_bytes(path.read_bytes())
    with netCDF4.Dataset(spoiled, "a") as nc:
        nc["depth"].units = "fathoms please"
        del nc["obs_time"].standard_name
    problems = _cf_problems(spoiled, tmp_path)
    assert any("depth" in p for p in problems), problems


def test_exports_carry_each_quantity_at_its_real_precision(
    survey: tuple[Path, SurveySummary], tmp_path: Path
) -> None:
    netCDF4 = pytest.importorskip("netCDF4")
    db, _ = survey
    with JournalReader(db) as reader:
        cast = reader.casts(cast_id=2)[0]
        samples = reader.samples(cast_id=2)
        fix = reader.fixes(cast_id=2)[0]
    noisy = 0.1 + 0.044  # 0.14400000000000002: what float arithmetic leaves behind
    cast = cast._replace(
        planned_depth_m=noisy,
        reached_depth_m=noisy,
        water_depth_m=3 * 1.1,
        lat_deg=40.45063081234,
        lon_deg=-3.72605791234,
    )
    samples = [samples[0]._replace(depth_m=noisy), *samples[1:]]
    fix = fix._replace(sonar_distance_m=3 * 1.1, lat_deg=40.45063081234)
    text = json.dumps(geojson.feature_collection([cast], [fix, fix]))
    assert "0.14400000000000002" not in text and "3.3000000000000003" not in text
    doc = json.loads(text)
    station = doc["features"][0]
    assert station["properties"]["planned_depth_m"] == 0.144
    assert station["properties"]["water_depth_m"] == 3.3
    assert station["geometry"]["coordinates"] == [-3.7260579, 40.4506308]
    assert doc["features"][-1]["properties"]["depth_m"] == 3.3

    path = tmp_path / "one.nc"
    netcdf.write([cast], samples, path)
    with netCDF4.Dataset(path) as nc:
        assert nc["planned_depth"][0] == 0.144
        assert nc["reached_depth"][0] == 0.144
        assert nc["depth"][0] == 0.144
        assert nc["lat"][0] == 40.4506308
        assert nc["depth"].dtype.str == "<f8"


def test_telemetry_csv_has_the_autopilots_clock_in_the_byte_order_it_settled_on(
    tmp_path: Path,
) -> None:
    from cc_daemon.core.protocol import Telemetry

    # The deployed firmware sends its seconds little-endian; the daemon reads them
    # big-endian until it has learnt the order (here after three frames), so the
    # journal holds 0, 256, 512 decoded "big", then 3, 4 decoded "little".
    clock = FakeClock()
    journal = Journal(tmp_path / "j.db", monotonic=clock.monotonic, wall=clock.wall)
    journal.open()
    for second, order in enumerate(["big", "big", "big", "little", "little"]):
        raw = second << 8  # the two bytes little-endian, read big-endian
        decoded = raw if order == "big" else second
        fix = Telemetry(raw, -37260579, 404506308, 0, 6000, 90)
        journal.record_fix(fix, ap_time_s=decoded, ap_time_order=order)
        clock.advance(1.0)
    journal.close()
    with JournalReader(tmp_path / "j.db") as reader:
        out = io.StringIO()
        csv_export.write_fixes(reader.fixes(), out)
    rows = list(csv.DictReader(io.StringIO(out.getvalue())))
    assert [int(r["autopilot_timestamp_s"]) for r in rows] == [0, 1, 2, 3, 4]
    assert {r["autopilot_byte_order"] for r in rows} == {"little"}
