"""The sonde's data out of a real journal: CSV, NetCDF-CF, GeoJSON and the profile plot."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import netCDF4
import pytest

from cc_daemon.cli.app import main
from cc_daemon.config.sonde import DEFAULT_PARAMETERS
from cc_daemon.core.protocol import StartMeasuring
from cc_daemon.store import Journal
from cc_daemon.store.sonde import SondeSampleRecord

NAMES = [p.name for p in DEFAULT_PARAMETERS]


def make_journal(path: Path) -> None:
    journal = Journal(path)
    journal.open()
    journal.record_event(
        "sonde_started",
        backend="modbus",
        parameters=[p.model_dump(by_alias=True, mode="json") for p in DEFAULT_PARAMETERS],
    )
    station = StartMeasuring(100, -37260579, 404506308, 0, 6000, 90)
    cast_id = journal.start_cast(station, planned_depth_m=3.0, mode="continuous", plan={})
    t = 100.0
    for i, (phase, depth) in enumerate(
        [("descending", d / 2) for d in range(7)] + [("ascending", d / 2) for d in range(6, -1, -1)]
    ):
        values: dict[str, float | None] = {
            "depth": depth,
            "temperature": 24.0 - depth,
            "ph": 8.4 - 0.1 * depth,
            "do_saturation": 100.0 - 10 * depth,
            "do_concentration": 8.8 - depth,
            "blue": 1.0,
            "chlorophyll": 2.0 + depth,
        }
        missing: dict[str, str] = {}
        if i == 3:
            values["ph"] = None
            missing["ph"] = "nan"
        journal.record_sonde_sample(
            cast_id=cast_id, phase=phase, mono_s=t + i, wall_s=1.7e9 + i, duration_s=0.08,
            status="partial" if missing else "ok", error=None, line_out_m=depth * 1.01,
            sonde_depth_m=depth, values=values, missing=missing, simulated=False,
        )  # fmt: skip
    journal.record_sonde_sample(
        cast_id=cast_id, phase="ascending", mono_s=t + 20, wall_s=1.7e9 + 20, duration_s=0.3,
        status="timeout", error="no reply", line_out_m=0.0, sonde_depth_m=None,
        values=dict.fromkeys(NAMES), missing=dict.fromkeys(NAMES, "timeout"), simulated=False,
    )  # fmt: skip
    journal.end_cast(cast_id, outcome="completed", reached_depth_m=3.0)
    journal.close()


@pytest.fixture
def db(tmp_path: Path) -> Path:
    path = tmp_path / "j.db"
    make_journal(path)
    return path


def test_csv_has_units_in_the_header_and_empty_missing_cells(
    db: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sonde", "export", "--db", str(db), "--format", "csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert len(rows) == 15
    assert "temperature [degC]" in rows[0] and "do_concentration [mg/L]" in rows[0]
    assert rows[0]["phase"] == "descending" and rows[0]["lat"] == "40.4506308"
    assert rows[3]["ph [1]"] == "" and rows[3]["missing"] == "ph:nan"
    assert rows[-1]["status"] == "timeout" and rows[-1]["temperature [degC]"] == ""
    assert rows[-1]["sonde_depth [m]"] == ""
    assert float(rows[2]["temperature [degC]"]) == 23.0


def test_netcdf_profiles_follow_cf(db: Path, tmp_path: Path) -> None:
    out = tmp_path / "p.nc"
    assert main(["sonde", "export", "--db", str(db), "--format", "netcdf", "-o", str(out)]) == 0
    with netCDF4.Dataset(out) as nc:
        assert nc.Conventions == "CF-1.8" and nc.featureType == "profile"
        assert list(nc["row_size"][:]) == [15]
        assert nc["row_size"].sample_dimension == "obs"
        assert nc["profile"].cf_role == "profile_id"
        assert nc["depth"].positive == "down" and nc["depth"].standard_name == "depth"
        t = nc["temperature"]
        assert t.standard_name == "sea_water_temperature" and t.units == "degC"
        assert nc["ph"].standard_name == "sea_water_ph_reported_on_total_scale"
        assert nc["do_concentration"].standard_name == "mass_concentration_of_oxygen_in_sea_water"
        assert nc["do_concentration"].units == "mg L-1"
        assert nc["do_saturation"].units == "percent"
        assert nc["do_saturation"].standard_name == "fractional_saturation_of_oxygen_in_sea_water"
        assert not hasattr(nc["blue"], "standard_name") and nc["blue"].units == "RFU"
        ph = nc["ph"][:]
        assert bool(ph.mask[3]) or math.isnan(float(ph[3]))  # missing, not 0
        # The timed-out reading: depth from the line out, flagged as such.
        assert int(nc["depth_source"][14]) == 1
        assert not hasattr(nc["sonde_depth"], "standard_name")


def test_geojson_stations_carry_surface_and_bottom(
    db: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sonde", "export", "--db", str(db), "--format", "geojson"]) == 0
    doc = json.loads(capsys.readouterr().out)
    (station,) = doc["features"]
    props = station["properties"]
    assert station["geometry"]["coordinates"] == [-3.7260579, 40.4506308]
    assert props["surface_depth_m"] == 0.0 and props["surface_temperature"] == 24.0
    assert props["bottom_depth_m"] == 3.0 and props["bottom_temperature"] == 21.0
    assert props["units"]["temperature"] == "degC"


def test_plot_writes_a_png(db: Path, tmp_path: Path) -> None:
    out = tmp_path / "c.png"
    assert main(["sonde", "plot", "--db", str(db), "--cast", "1", "-o", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_no_such_cast(db: Path, tmp_path: Path) -> None:
    assert main(["sonde", "plot", "--db", str(db), "--cast", "9", "-o", str(tmp_path / "x")]) == 1


def test_simulator_summary_lines(db: Path) -> None:
    from cc_daemon.sim.sondesummary import sonde_lines

    (line,) = sonde_lines(db, 1)  # the journal's one session
    assert line.startswith("cast 1 (S1) sonde: 15 readings, 2 incomplete; surface 0.00 m")
    assert "temperature 24.00 degC" in line and "bottom 3.00 m" in line
    assert "ph 8.10," in line  # pH's unit "1" is not printed


def test_survey_map_and_section(db: Path, tmp_path: Path) -> None:
    base = ["sonde", "plot", "--db", str(db), "--survey", "--parameter", "temperature"]
    assert main([*base, "--depth", "2", "-o", str(tmp_path / "m.png")]) == 0
    assert main([*base, "--section", "-o", str(tmp_path / "s.png")]) == 0
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "s.png").read_bytes()[:4] == b"\x89PNG"
    assert main([*base, "-o", str(tmp_path / "x.png")]) == 2  # neither --depth nor --section
    assert main([*base[:-1], "bogus", "--section", "-o", str(tmp_path / "x.png")]) == 1


def test_value_near_and_distance() -> None:
    from cc_daemon.export.sondeplot import along_track_m, value_near
    from cc_daemon.store.reader import CastRecord

    def reading(depth: float | None, value: float | None) -> SondeSampleRecord:
        return SondeSampleRecord(1, "descending", 0.0, 0.0, True, 0.1, "ok", None, depth,
                                 depth, False, {"t": value}, {})  # fmt: skip

    rows = [reading(1.0, 10.0), reading(1.9, 12.0), reading(2.3, None), reading(None, 9.0)]
    assert value_near(rows, "t", 2.0, 0.5) == 12.0
    assert value_near(rows, "t", 5.0, 0.5) is None

    def cast(i: int, lat: float) -> CastRecord:
        return CastRecord(i, None, 0, 0, True, 0, lat, 0.0, 0, 0, 0, 1, "c", {}, None, None,
                          None, None, None, 0)  # fmt: skip

    first, second = along_track_m([cast(1, 40.0), cast(2, 40.001)])
    assert first == 0.0 and second == pytest.approx(111.2, abs=0.1)


def test_a_refused_stations_readings_are_not_called_a_profile(tmp_path: Path) -> None:
    from cc_daemon.sim.sondesummary import sonde_lines

    path = tmp_path / "j.db"
    journal = Journal(path)
    journal.open()
    held = journal.start_cast(  # --winch-fail-home: refused, the probe hung at 0.50 m
        StartMeasuring(1, -37260579, 404506308, 0, 5900, 97), planned_depth_m=0.0,
        mode="continuous", plan={},
    )  # fmt: skip
    for i in range(3):
        journal.record_sonde_sample(
            cast_id=held, phase="stranded", mono_s=100.0 + i, wall_s=1.7e9 + i, duration_s=0.08,
            status="ok", error=None, line_out_m=0.5, sonde_depth_m=0.5,
            values={"depth": 0.5, "temperature": 23.9}, missing={}, simulated=True,
        )  # fmt: skip
    journal.end_cast(held, outcome="unfinished", reached_depth_m=0.5)
    journal.close()
    (line,) = sonde_lines(path, 1)
    assert line.startswith("cast 1 (S1, refused: the probe held where it stranded) sonde")
