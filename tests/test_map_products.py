"""`cc-daemon map`'s products, each read back by its reference reader, and the map judged
against the simulator's true bed.

A lines survey (six lines of 150 m, 20 m apart, 3 % outliers, 5 % dropouts, both
echosounders at their drafts, a GPS glitch now and then) is written into a real
journal from the simulator's models; the command maps it. The NetCDF grid is read
with netCDF4 and checked by the IOOS compliance checker (CF 1.8 and ACDD 1.3), the
GeoTIFF with rasterio (GDAL), the contours with the geojson validator, the table
with the csv module, the map as an image.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("scipy")
pytest.importorskip("pyproj")
pytest.importorskip("netCDF4")
pytest.importorskip("matplotlib")

from cc_daemon.config.survey import SurveySettings
from cc_daemon.export import bathy_csv
from cc_daemon.export.bathymap import MapOptions, make_map, survey_hypsography
from cc_daemon.export.mapproducts import write_all
from cc_daemon.science.bathymetry import qc
from cc_daemon.store import JournalReader
from tests.bathykit import AUTOPILOT_DRAFT_M, ONBOARD_DRAFT_M, lines_journal, true_depth

WHO = {
    "creator_name": "Ana Limnóloga",
    "creator_email": "ana@lab.example.org",
    "creator_url": "https://lab.example.org",
    "institution": "Lake Lab",
    "project": "Reservoir bathymetry",
    "license": "CC-BY-4.0",
}
SETTINGS = SurveySettings(
    autopilot_draft_m=AUTOPILOT_DRAFT_M, onboard_draft_m=ONBOARD_DRAFT_M, **WHO
)


@pytest.fixture(scope="module")
def survey(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    db = tmp_path_factory.mktemp("lake") / "lake.db"
    truth = lines_journal(db, glitch_rate=0.002)
    return db, truth


@pytest.fixture(scope="module")
def mapped(survey: tuple[Path, Any], tmp_path_factory: pytest.TempPathFactory) -> Any:
    db, _ = survey
    with JournalReader(db) as reader:
        chosen = reader.select_survey("latest")
        assert chosen is not None
        made = make_map(reader, chosen, MapOptions(survey=SETTINGS, water_level_m=702.4))
    out = tmp_path_factory.mktemp("products")
    return made, write_all(made, out)


def test_the_map_meets_the_true_bed_and_the_qc_finds_the_outliers(
    survey: tuple[Path, Any], mapped: Any
) -> None:
    _, truth = survey
    made, _ = mapped
    grid = made.bed.grid
    gx, gy = np.meshgrid(grid.spec.x, grid.spec.y)
    error = (grid.depth_m - true_depth(truth, made.soundings.crs, gx, gy))[grid.mapped]
    assert np.sqrt(np.mean(error**2)) < 0.10 and abs(error.mean()) < 0.03
    assert made.bed.spacing_m == pytest.approx(20.0, rel=0.05)
    assert made.bed.cell_m == 5.0 and made.bed.max_distance_m == pytest.approx(15.0, rel=0.05)
    kinds = np.array([k.value for k in truth.fix_kinds + truth.ping_kinds])
    outlier = np.isin(kinds, ["second echo", "shallow return"])
    rejected = ~made.soundings.kept
    assert rejected[outlier].mean() >= 0.95
    assert rejected[kinds == "good"].mean() <= 0.02
    # Every GPS glitch is found: the fix, and the readings it would have placed.
    reasons = made.soundings.reason[: truth.fixes]
    assert (reasons[np.array(truth.jumped)] != qc.Reason.KEPT).all()
    assert (made.soundings.reason == qc.Reason.POSITION_JUMP).sum() == sum(truth.jumped)


def test_drafts_put_each_source_at_the_water_surface(survey: tuple[Path, Any]) -> None:
    """Without its draft each echosounder reads its own depth short: the map is shallower
    by about the drafts' mean, and the two sources disagree."""
    db, truth = survey
    with JournalReader(db) as reader:
        chosen = reader.select_survey("latest")
        assert chosen is not None
        bare = make_map(reader, chosen, MapOptions(survey=SurveySettings()))
    kept = bare.soundings.kept
    x, y = bare.soundings.x_m, bare.soundings.y_m
    miss = bare.soundings.depth_m - true_depth(truth, bare.soundings.crs, x, y)
    for source, draft in ((0, AUTOPILOT_DRAFT_M), (1, ONBOARD_DRAFT_M)):
        these = kept & (bare.soundings.source == source)
        assert np.median(miss[these]) == pytest.approx(-draft, abs=0.01)


def test_the_netcdf_grid_reads_back_and_passes_cf_and_acdd(mapped: Any, tmp_path: Path) -> None:
    import netCDF4

    made, paths = mapped
    grid = made.bed.grid
    with netCDF4.Dataset(paths["grid"]) as nc:
        depth = nc["depth"][:]
        assert np.ma.is_masked(depth) or not (~grid.mapped).any()
        assert np.ma.getmaskarray(depth).tolist() == (~grid.mapped).tolist()
        assert depth.compressed() == pytest.approx(grid.depth_m[grid.mapped], abs=6e-4)
        assert nc["depth"].grid_mapping == "crs"
        from pyproj import CRS

        assert CRS.from_wkt(nc["crs"].getncattr("crs_wkt")).to_epsg() == 32630
        assert nc["crs"].grid_mapping_name == "transverse_mercator"
        assert np.asarray(nc["x"][:]).tolist() == pytest.approx(grid.spec.x.tolist())
        assert float(nc["lat"][:].min()) == pytest.approx(40.45, abs=0.01)
        elevation = nc["bed_elevation"][:]
        assert (elevation + depth).compressed() == pytest.approx(702.4, abs=1e-3)
        assert nc.cv_rmse_m == pytest.approx(made.bed.cv.rmse_m)
        assert nc.soundings_rejected_spike == made.soundings.counts()["spike"]
        assert nc.simulated == "yes" and nc.title.startswith("SIMULATED")
    assert checker(paths["grid"], "cf:1.8", tmp_path) == []
    # Everything ACDD 1.3 asks is there but two comparisons a 2-D grid of the bed cannot
    # offer (it has no vertical or time coordinate to compare the extents with) and a
    # standard name no quantity in the CF table has (the distance to a sounding).
    assert sorted(checker(paths["grid"], "acdd:1.3", tmp_path, scores=False)) == [
        "geospatial_vertical_extents_match: Could not find vertical variable to test extent of"
        " geospatial_vertical_min/geospatial_vertical_max, see CF-1.6 spec chapter 4.3",
        "time_coverage_extents_match: Could not find time variable to test extent of"
        " time_coverage_start/time_coverage_end, see CF-1.6 spec chapter 4.4",
        'variable "distance_to_sounding" missing the following attributes:: standard_name',
    ]


def checker(path: Path, suite: str, tmp_path: Path, *, scores: bool = True) -> list[str]:
    """What the IOOS compliance checker's `suite` says about `path`, every priority."""
    runner = pytest.importorskip("compliance_checker.runner")
    runner.CheckSuite().load_all_available_checkers()
    report = tmp_path / f"{path.stem}-{suite.replace(':', '')}.json"
    with warnings.catch_warnings():
        # The checker's ACDD suite warns about its own calling convention: not ours.
        warnings.simplefilter("ignore", DeprecationWarning)
        _, errors = runner.ComplianceChecker.run_checker(
            str(path), [suite], 0, "strict", output_filename=str(report), output_format="json"
        )
    assert not errors
    (result,) = json.loads(report.read_text()).values()
    problems = [f"{c['name']}: {m}" for c in result["all_priorities"] for m in c["msgs"]]
    if scores and result["scored_points"] != result["possible_points"]:
        problems.append(f"scored {result['scored_points']} of {result['possible_points']}")
    return problems


def test_the_geotiff_opens_in_gdal_with_its_crs_and_its_cells(mapped: Any) -> None:
    rasterio = pytest.importorskip("rasterio")
    made, paths = mapped
    spec = made.bed.grid.spec
    with rasterio.open(paths["geotiff"]) as tif:
        assert tif.crs.to_epsg() == made.epsg == 32630
        assert tif.nodata == -9999.0
        assert (tif.width, tif.height) == (spec.nx, spec.ny)
        assert tif.transform.a == spec.cell_m and tif.transform.e == -spec.cell_m
        assert tif.transform.c == spec.x0 and tif.transform.f == spec.y0 + spec.ny * spec.cell_m
        band = tif.read(1, masked=True)
    # North up: the file's first row is the grid's last.
    expected = np.ma.masked_invalid(made.bed.grid.depth_m[::-1])
    assert np.ma.getmaskarray(band).tolist() == np.ma.getmaskarray(expected).tolist()
    assert band.compressed() == pytest.approx(expected.compressed(), abs=1e-5)


def test_the_contours_are_valid_rfc7946_geojson_in_wgs84(mapped: Any) -> None:
    geojson = pytest.importorskip("geojson")
    made, paths = mapped
    text = paths["contours"].read_text()
    doc = geojson.loads(text)
    assert doc.is_valid, doc.errors()
    assert "crs" not in json.loads(text)  # RFC 7946: WGS 84 only, no crs member
    depths = [f["properties"]["depth_m"] for f in doc["features"]]
    assert depths == sorted(depths) and len(depths) >= 3
    finite = made.bed.grid.depth_m[made.bed.grid.mapped]
    assert finite.min() < depths[0] and depths[-1] < finite.max()
    for feature in doc["features"]:
        assert feature["geometry"]["type"] == "MultiLineString"
        for line in feature["geometry"]["coordinates"]:
            lon, lat = np.array(line).T
            assert (np.abs(lon + 3.725) < 0.01).all() and (np.abs(lat - 40.451) < 0.01).all()


def test_the_hypsography_table_is_the_science_floors_value(mapped: Any) -> None:
    made, paths = mapped
    with paths["hypsography"].open(newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == list(bathy_csv.HEADER) == ["depth_m", "area_m2", "volume_m3"]
    table = np.array(rows[1:], dtype=float)
    hyps = made.bed.hypsography
    assert table[:, 0] == pytest.approx(hyps.depth_m, abs=5e-4)
    assert table[:, 1] == pytest.approx(hyps.area_m2, abs=0.05)
    assert table[:, 2] == pytest.approx(hyps.volume_m3, abs=0.05)
    assert hyps.area_m2[0] == pytest.approx(made.bed.grid.mapped_area_m2)


def test_the_png_map_is_metric_labelled_and_says_simulated(mapped: Any) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.image import imread

    from cc_daemon.export import bathyplot, contours_geojson

    made, paths = mapped
    assert imread(paths["map"]).shape[2] in (3, 4)
    fig = bathyplot.map_figure(made, contours_geojson.map_contours(made))
    fig.draw(FigureCanvasAgg(fig).get_renderer())
    ax = next(a for a in fig.axes if a.get_label() != "<colorbar>")
    box = ax.get_window_extent()
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert box.width / (x1 - x0) == pytest.approx(box.height / (y1 - y0), rel=1e-2)
    texts = [t.get_text() for t in ax.texts] + [t.get_text() for t in fig.texts]
    assert "SIMULATED" in texts
    assert any(t.endswith(" m") and t[0].isdigit() for t in texts)  # contour labels
    # The stations named as the simulator's table and every command name them.
    assert made.casts and {made.station_names[c.id] for c in made.casts} <= set(texts)
    assert all(name.startswith("S") for name in made.station_names.values())
    colourbar = next(a for a in fig.axes if a.get_label() == "<colorbar>")
    assert "(m)" in colourbar.get_ylabel()
    assert "cross-validated RMSE" in ax.get_title()
    legend = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    assert any(t.startswith("not mapped") for t in legend) and "station" in legend
    bars = [a for a in ax.artists if type(a).__name__ == "AnchoredSizeBar"]
    assert len(bars) == 1


def test_the_summary_says_what_a_field_team_asks(mapped: Any) -> None:
    made, paths = mapped
    text = paths["summary"].read_text()
    counts = made.soundings.counts()
    assert text.startswith("SIMULATED survey 1")
    assert f"{counts['kept']} used" in text and f"{counts['spike']} spike" in text
    assert "cross-validated RMSE" in text and "(an estimate" in text
    figures = json.loads(paths["figures"].read_text())
    assert figures["soundings"] == counts
    assert figures["volume_m3"] == pytest.approx(float(made.bed.hypsography.volume_m3[0]))


def test_survey_hypsography_for_schmidt_stability(survey: tuple[Path, Any], tmp_path: Path) -> None:
    db, _ = survey
    hyps, why = survey_hypsography(db, 1)
    assert hyps is not None and why == "" and hyps.depth_m[0] == 0.0
    missing, why = survey_hypsography(db, 7)
    assert missing is None and "no survey 7" in why
    empty = tmp_path / "empty.db"
    lines_journal(empty, lines=1, line_length_m=3.0)  # a handful of soundings on one line
    none, why = survey_hypsography(empty, 1)
    assert none is None and why
    sketch = tmp_path / "sketch.db"
    lines_journal(sketch, lines=2, line_length_m=60.0)  # mapped, its accuracy not estimated
    with JournalReader(sketch) as reader:
        chosen = reader.select_survey(1)
        assert chosen is not None
        made = make_map(reader, chosen, MapOptions())
    assert made.bed.hypsography is not None and math.isnan(made.bed.cv.rmse_m)
    none, why = survey_hypsography(sketch, 1)
    assert none is None and "too little of the lake to trust" in why


def test_readings_are_placed_only_between_fixes_of_their_own_session(tmp_path: Path) -> None:
    from cc_daemon.export.soundings import _place

    fix_session = np.array([1, 1, 1, 2, 2])
    fix_mono = np.array([0.0, 1.0, 10.0, 100.0, 101.0])
    fix_x = np.array([0.0, 1.5, 15.0, 500.0, 501.5])
    session = np.array([1, 1, 1, 2, 1])
    mono = np.array([0.5, 5.0, -1.0, 100.5, 100.5])
    x, _ = _place(fix_session, fix_mono, fix_x, np.zeros(5), session, mono, 3.0)
    # Between two fixes 1 s apart: interpolated. Across a 9 s gap, before the first fix,
    # and at a time only another session has fixes for: not placed.
    assert x[0] == pytest.approx(0.75) and x[3] == pytest.approx(500.75)
    assert np.isnan(x[[1, 2, 4]]).all()


def run_map(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cc_daemon", "map", *args],
        check=False, capture_output=True, text=True, timeout=240, cwd=cwd,
        env={"PATH": "/usr/bin:/bin", "HOME": str(cwd)},
    )  # fmt: skip


def test_the_command_writes_every_product_and_says_what_it_cannot_do(
    survey: tuple[Path, Any], tmp_path: Path
) -> None:
    db, _ = survey
    out = tmp_path / "map"
    config = tmp_path / "lab.toml"
    config.write_text("[survey]\nautopilot_draft_m = 0.1\n")
    done = run_map(
        "--db", str(db), "-o", str(out), "--water-level", "702.4", "--config", str(config),
        cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    names = {p.name for p in out.iterdir()}
    assert names == {"bathymetry.nc", "depth.tif", "contours.geojson", "hypsography.csv",
                     "map.png", "summary.txt", "summary.json"}  # fmt: skip
    assert "cross-validated RMSE" in done.stdout and "water level      702.4 m" in done.stdout
    assert "survey.creator_name" in done.stderr  # who made it: not configured here
    config.write_text("[survey]\n" + "".join(f'{k} = "{v}"\n' for k, v in WHO.items()))
    whole = run_map("--db", str(db), "-o", str(out), "--config", str(config), cwd=tmp_path)
    assert whole.returncode == 0 and "note:" not in whole.stderr
    failed = run_map("--db", str(db), "-o", str(tmp_path / "x"), "--survey", "9", cwd=tmp_path)
    assert failed.returncode == 1 and "no survey 9" in failed.stderr
    assert run_map("--db", str(db), "-o", str(out), "--survey", "all", cwd=tmp_path).returncode == 2
    assert run_map("--db", str(db), "-o", str(out), "--cell", "-5", cwd=tmp_path).returncode == 2
    config.write_text("[survey]\nmin_confidence_pct = 150\n")
    bad = run_map("--db", str(db), "-o", str(out), "--config", str(config), cwd=tmp_path)
    assert bad.returncode == 2 and "survey.min_confidence_pct" in bad.stderr
    missing = run_map("--db", str(tmp_path / "none.db"), "-o", str(out), cwd=tmp_path)
    assert missing.returncode == 1 and missing.stderr.count("\n") <= 2
    from cc_daemon.store import Journal

    empty = tmp_path / "empty.db"
    journal = Journal(empty)
    journal.open()
    journal.close()
    nothing = run_map("--db", str(empty), "-o", str(out), cwd=tmp_path)
    assert nothing.returncode == 1 and "Traceback" not in nothing.stderr
    assert "no survey" in nothing.stderr
