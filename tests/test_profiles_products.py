"""`cc-daemon profiles` end to end on a real journal of simulated casts: every product read
back with its own reader (netCDF4 and the CF checker, csv, json, matplotlib's PNG reader)."""

from __future__ import annotations

import csv
import io
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cc_daemon.cli.app import main
from cc_daemon.science.hypsography import Hypsography
from cc_daemon.science.limnology.schmidt import schmidt_stability_in
from cc_daemon.sim.profilecast import CastShape
from cc_daemon.sim.water import WaterColumn
from tests.profilekit import CastSpec, write_journal
from tests.test_export import _cf_problems

pytest.importorskip("netCDF4")
pytest.importorskip("matplotlib")

CASTS = [
    CastSpec(WaterColumn(), seed=1, north_m=0.0, sonar_m=8.0),
    CastSpec(WaterColumn(thermocline_m=2.5), seed=2, north_m=150.0, sonar_m=6.0),
    CastSpec(WaterColumn(surface_temp_c=18.0, bottom_temp_c=18.0), seed=3, north_m=300.0,
             sonar_m=5.6),
    CastSpec(WaterColumn(hypolimnion_do_saturation_pct=5.0), seed=4, north_m=450.0,
             sonar_m=None, shape=CastShape(depth_m=8.0)),
]  # fmt: skip
LAKE_CSV = "depth_m,area_m2,volume_m3\n" + "".join(
    f"{z},{250_000 * (1 - z / 12) ** 1.5:.1f},0\n" for z in range(13)
)


def run(*args: str, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(["profiles", *args])
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def journal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("profiles") / "survey.db"
    write_journal(path, CASTS)
    return path


@pytest.fixture(scope="module")
def products(journal: Path) -> tuple[Path, str]:
    out = journal.parent / "out"
    saved = sys.stderr
    sys.stderr = io.StringIO()
    try:
        code = main(["profiles", "--db", str(journal), "-o", str(out)])
        said = sys.stderr.getvalue()
    finally:
        sys.stderr = saved
    assert code == 0, said
    return out, said


def rows(path: Path) -> list[dict[str, str]]:
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith("# cc-daemon profiles: winch_backend: unknown; simulated:")
    return list(csv.DictReader(lines[1:]))


def test_the_command_names_every_product_and_why_schmidt_is_missing(
    products: tuple[Path, str],
) -> None:
    out, said = products
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["profiles.nc", "profiles.csv", "stations.csv", "stations.geojson"]
        + [f"cast-{n}.png" for n in (1, 2, 3, 4)]
        + [f"section-{p}.png" for p in
           ("temperature", "ph", "do_saturation", "do_concentration", "blue", "chlorophyll")]
    )  # fmt: skip
    assert f"wrote {out / 'profiles.nc'}: 8 profiles (4 casts, down and up) on " in said
    schmidt = [line for line in said.splitlines() if line.startswith("Schmidt stability")]
    assert len(schmidt) == 1
    assert schmidt[0].startswith(
        "Schmidt stability: missing (an empty cell, flagged no_hypsography): it needs the "
        "lake's hypsography, and the survey's own soundings could not make one ("
    )
    assert schmidt[0].endswith(
        "); give --hypsography FILE (a depth_m,area_m2,volume_m3 table, as `cc-daemon map` "
        "writes it)"
    )


def test_the_netcdf_is_cf_profiles_the_checker_passes(
    products: tuple[Path, str], tmp_path: Path
) -> None:
    import netCDF4

    out, _ = products
    path = out / "profiles.nc"
    assert _cf_problems(path, tmp_path) == []
    with netCDF4.Dataset(path) as nc:
        assert nc.featureType == "profile" and nc.Conventions == "CF-1.8"
        assert list(nc["cast_id"][:]) == [1, 1, 2, 2, 3, 3, 4, 4]
        assert list(nc["way"][:]) == [0, 1] * 4 and nc["way"].flag_meanings == "down up"
        depth = nc["depth"][:]
        assert depth[0] == 0.0 and np.allclose(np.diff(depth), 0.25)
        t = nc["temperature"]
        assert t.standard_name == "sea_water_temperature" and t.units == "degC"
        assert t.dimensions == ("profile", "depth")
        assert t.ancillary_variables == (
            "temperature_mean temperature_sd temperature_count temperature_flag"
        )
        assert nc["temperature_count"].standard_name == "number_of_observations"
        counts = nc["temperature_count"][:]
        flags = nc["temperature_flag"][:]
        values = np.ma.filled(t[:], np.nan)
        assert ((counts == 0) == (flags == 2)).all() and np.isnan(values[counts == 0]).all()
        assert not np.isnan(values[counts > 0]).any()
        assert set(np.unique(flags)) <= {0, 1, 2}
        # Cast 1's way down is the simulator's water: within 0.2 degC at every bin.
        down = counts[0] > 0
        truth = [WaterColumn().truth(d, 0.0)["temperature"] for d in depth[down]]
        assert values[0][down] == pytest.approx(truth, abs=0.2)
        assert nc.simulated == "unknown" and "SIMULATED DATA" in nc.comment


def test_the_csv_holds_the_same_profiles(products: tuple[Path, str]) -> None:
    import netCDF4

    out, _ = products
    table = rows(out / "profiles.csv")
    assert {r["way"] for r in table} == {"down", "up"}
    first = [r for r in table if r["cast_id"] == "1" and r["way"] == "down"]
    with netCDF4.Dataset(out / "profiles.nc") as nc:
        depth = list(nc["depth"][:])
        values = nc["temperature"][0]
        means = nc["temperature_mean"][0]
        for r in first:
            i = depth.index(float(r["depth [m]"]))
            assert float(r["temperature [degC]"]) == pytest.approx(float(values[i]), abs=1e-4)
            assert float(r["temperature_mean [degC]"]) == pytest.approx(float(means[i]), abs=1e-4)
    assert all(r["temperature_flag"] in ("", "few") for r in first)
    assert any(r["temperature_sd [degC]"] == "" and r["temperature_n"] == "1" for r in table)
    assert all(abs(float(r["readings_depth [m]"]) - float(r["depth [m]"])) <= 0.125 + 1e-3
               for r in table)  # fmt: skip


def stations(products: tuple[Path, str]) -> list[dict[str, str]]:
    return rows(products[0] / "stations.csv")


def test_the_stations_table_reads_each_cast(products: tuple[Path, str]) -> None:
    sim, shallower, mixed, hypoxic = stations(products)
    assert float(sim["thermocline [m]"]) == pytest.approx(3.77, abs=0.15)
    assert float(shallower["thermocline [m]"]) == pytest.approx(2.27, abs=0.15)
    assert float(sim["metalimnion_top [m]"]) < 3.77 < float(sim["metalimnion_bottom [m]"])
    assert float(sim["dcm [m]"]) == pytest.approx(3.0, abs=0.1)
    assert float(sim["bed [m]"]) == 8.0 and hypoxic["bed [m]"] == ""
    # A mixed column: no thermocline, and said why; never a 0.
    assert mixed["thermocline [m]"] == "" and mixed["metalimnion_top [m]"] == ""
    missing = dict(item.split(":") for item in mixed["missing"].split(";"))
    assert missing["thermocline"] == "mixed" and missing["schmidt_stability"] == "no_hypsography"
    assert all(s["schmidt_stability [J/m2]"] == "" for s in (sim, shallower, mixed, hypoxic))
    assert float(hypoxic["hypoxia_top [m]"]) == pytest.approx(5.26, abs=0.15)
    assert "hypoxia_top:not_reached" in sim["missing"] and "bed:cast_blind" in hypoxic["missing"]
    assert float(sim["surface_depth [m]"]) == 0.0 and float(sim["bottom_depth [m]"]) == 5.0
    assert float(sim["surface_temperature [degC]"]) == pytest.approx(24.0, abs=0.1)


def test_the_geojson_is_rfc_7946_points_with_the_same_numbers(products: tuple[Path, str]) -> None:
    doc = json.loads((products[0] / "stations.geojson").read_text(), parse_constant=_no_nan)
    assert doc["type"] == "FeatureCollection" and len(doc["features"]) == 4
    table = stations(products)
    for feature, row in zip(doc["features"], table, strict=True):
        assert feature["type"] == "Feature" and feature["geometry"]["type"] == "Point"
        lon, lat = feature["geometry"]["coordinates"]  # longitude first (RFC 7946, 3.1.1)
        assert (lat, lon) == (float(row["lat"]), float(row["lon"]))
        props = feature["properties"]
        if row["thermocline [m]"]:
            assert props["thermocline"] == pytest.approx(float(row["thermocline [m]"]), abs=1e-4)
        else:
            assert props["thermocline"] is None and props["missing"]["thermocline"] == "mixed"
        assert props["units"]["schmidt_stability"] == "J/m2"
        assert props["schmidt_stability"] is None


def _no_nan(word: str) -> Any:
    raise AssertionError(f"{word} in a GeoJSON file (not JSON)")


def test_a_hypsography_gives_schmidt_stability(
    journal: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    lake_file = tmp_path / "lake.csv"
    lake_file.write_text(LAKE_CSV)
    code, said = run("--db", str(journal), "-o", str(tmp_path / "o"), "--no-plots",
                     "--hypsography", str(lake_file), capsys=capsys)  # fmt: skip
    assert code == 0 and "Schmidt stability: missing" not in said
    assert "covers" not in said
    table = rows(tmp_path / "o" / "stations.csv")
    assert not list((tmp_path / "o").glob("*.png"))
    values = [float(r["schmidt_stability [J/m2]"]) for r in table]
    assert values[2] == pytest.approx(0.0, abs=0.5)  # the mixed column
    assert values[0] > 50 and values[1] > 50
    # The number is the science's, from the bins of the published profile.
    first = [r for r in rows(tmp_path / "o" / "profiles.csv") if r["cast_id"] == "1"]
    down = [r for r in first if r["way"] == "down" and r["temperature_n"] != "0"]
    z = [float(r["depth [m]"]) for r in down]
    t = [float(r["temperature [degC]"]) for r in down]
    lake = Hypsography(
        depth_m=np.arange(13.0),
        area_m2=np.array([round(250_000 * (1 - z / 12) ** 1.5, 1) for z in range(13)]),
        volume_m3=np.zeros(13),
    )
    assert values[0] == pytest.approx(schmidt_stability_in(t, z, lake), abs=1e-2)


def test_a_partial_hypsography_is_said(
    journal: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    lake_file = tmp_path / "lake.csv"
    lines = LAKE_CSV.splitlines()
    lake_file.write_text(
        "# the bed mapped under 80 % of the water\n"
        + lines[0] + ",covered_fraction\n"
        + "".join(f"{line},0.8\n" for line in lines[1:])
    )  # fmt: skip
    code, said = run("--db", str(journal), "-o", str(tmp_path / "o"), "--no-plots",
                     "--hypsography", str(lake_file), capsys=capsys)  # fmt: skip
    assert code == 0 and "note: the hypsography covers 80% of the lake" in said


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ("depth,area\n0,1\n", "no column depth_m, area_m2, volume_m3"),
        ("depth_m,area_m2,volume_m3\n0,100,5\n1,x,2\n", "row 3: area_m2 'x' is not a number"),
        ("depth_m,area_m2,volume_m3\n0,100,5\n2,120,1\n", "areas must be >= 0 and never grow"),
        ("depth_m,area_m2,volume_m3\n1,100,5\n2,50,1\n", "depths must start at 0"),
        ("depth_m,area_m2,volume_m3\n0,100,5\n", "two depths or more"),
    ],
)
def test_a_bad_hypsography_is_one_line_and_nothing_written(
    journal: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, error: str
) -> None:
    lake_file = tmp_path / "lake.csv"
    lake_file.write_text(text)
    code, said = run("--db", str(journal), "-o", str(tmp_path / "o"),
                     "--hypsography", str(lake_file), capsys=capsys)  # fmt: skip
    assert code == 1 and said.count("\n") == 1 and error in said, said
    assert said.startswith(f"cc-daemon profiles: {lake_file}: ")
    assert not (tmp_path / "o").exists()


def test_bad_usage_and_no_data(
    journal: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a_file = tmp_path / "f"
    a_file.write_text("")
    assert run("--db", str(journal), "-o", str(a_file), capsys=capsys)[0] == 2
    with pytest.raises(SystemExit) as caught:
        main(["profiles", "--db", str(journal), "-o", str(tmp_path / "o"), "--bin-m", "0"])
    assert caught.value.code == 2
    code, said = run("--db", str(journal), "--cast", "9", "-o", str(tmp_path / "o"),
                     capsys=capsys)  # fmt: skip
    assert code == 1 and "no cast 9" in said
    empty = tmp_path / "empty.db"
    write_journal(empty, [])
    code, said = run("--db", str(empty), "-o", str(tmp_path / "o"), capsys=capsys)
    assert code == 1 and "no cast has sonde readings" in said


def test_one_cast_and_a_bin_of_its_own(journal: Path, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    code, said = run("--db", str(journal), "--cast", "2", "--bin-m", "0.5", "-o",
                     str(tmp_path / "o"), capsys=capsys)  # fmt: skip
    assert code == 0
    assert "on 11 bins of 0.5 m" in said  # 0 to 5 m
    assert "no section of temperature: a section of temperature needs two stations" in said
    assert [r["cast_id"] for r in rows(tmp_path / "o" / "stations.csv")] == ["2"]


def test_an_old_journal_without_response_times_uses_the_shipped_ones(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db = tmp_path / "old.db"
    write_journal(db, CASTS[:1], response_times=False)
    code, said = run("--db", str(db), "-o", str(tmp_path / "o"), "--no-plots", capsys=capsys)
    assert code == 0
    assert (
        "note: the journal holds no response times (written before they were configured): "
        "the shipped map's are used (temperature 2 s, ph 4 s" in said
    )


def test_without_netcdf4_the_tables_are_still_written(
    journal: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    monkeypatch.setitem(sys.modules, "netCDF4", None)
    code, said = run("--db", str(journal), "-o", str(tmp_path / "o"), "--no-plots", capsys=capsys)
    assert code == 1 and "profiles.nc not written" in said and "pip install" in said
    assert (tmp_path / "o" / "stations.csv").exists()
    assert not (tmp_path / "o" / "profiles.nc").exists()


def test_a_lag_correction_of_none_is_the_sensors_as_read(
    journal: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, _ = run("--db", str(journal), "--cast", "1", "-o", str(tmp_path / "o"),
                  "--no-plots", "--lag-correction", "none", capsys=capsys)  # fmt: skip
    assert code == 0
    raw = rows(tmp_path / "o" / "stations.csv")[0]
    assert math.isfinite(float(raw["thermocline [m]"]))
    line = (tmp_path / "o" / "profiles.csv").read_text().splitlines()[0]
    assert "sensor lags not corrected" in line


def test_the_surveys_own_soundings_give_its_hypsography(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without --hypsography, the survey's soundings are mapped as `cc-daemon map` maps
    them, and Schmidt stability reads that lake (docs/profiles.md)."""
    pytest.importorskip("scipy")
    from cc_daemon.cli.profiles import _survey_lake
    from cc_daemon.export.bathymap import survey_hypsography
    from cc_daemon.store import JournalReader
    from tests.bathykit import lines_journal

    db = tmp_path / "lines.db"
    lines_journal(db)
    with JournalReader(db) as reader:
        reader.select_survey("latest")
        casts = reader.casts()
        survey = reader.survey
    lake, why = _survey_lake(db, survey, casts)
    assert why == "" and lake is not None
    mapped, _ = survey_hypsography(db, casts[0].session_id or 0)
    assert mapped is not None and np.array_equal(lake.area_m2, mapped.area_m2)
    assert lake.area_m2[0] > 0 and lake.volume_m3[0] > 0
    assert "from the hypsography of this survey's own soundings" in capsys.readouterr().err
