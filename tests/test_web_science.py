"""The day's science on the field page (issue 29): `/api/surveys/N/science` and the
science's downloads are the files `cc-daemon map` and `cc-daemon profiles` write, each
opened by its reader; a survey is made once and again only when its journal changed
and the making is due; what cannot be made says why; the page's files go when it stops.
The page's server in this process (aiohttp's test client) over real journals: a lines
survey (its soundings) and, after it, a survey of sonde casts."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import subprocess
import sys
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from aiohttp.test_utils import TestClient

from cc_daemon.cli.web import science
from cc_daemon.cli.web.server import Sources
from cc_daemon.store import JournalReader
from tests import bathykit, webkit
from tests.profilekit import CastSpec, write_journal

pytestmark = pytest.mark.slow
LINES, CASTS = 1, 2  # the journal's surveys


@pytest.fixture(scope="module")
def journal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    db = tmp_path_factory.mktemp("science") / "day.db"
    bathykit.lines_journal(db, lines=5, line_length_m=120.0)
    write_journal(db, [CastSpec(seed=1), CastSpec(seed=2, north_m=60.0)])
    return db


@pytest.fixture(scope="module")
def commands(journal: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """What the commands write for the same surveys: map/ and profiles/."""
    out = tmp_path_factory.mktemp("commands")
    run = [sys.executable, "-m", "cc_daemon"]
    for args in (
        ["map", "--db", str(journal), "--survey", str(LINES), "-o", str(out / "map")],
        ["profiles", "--db", str(journal), "--survey", str(CASTS), "-o", str(out / "profiles"),
         "--no-plots"],
    ):  # fmt: skip
        done = subprocess.run(
            [*run, *args],
            check=False,
            capture_output=True,
            text=True,
            timeout=300,
            stdin=subprocess.DEVNULL,
        )
        assert done.returncode == 0, done.stderr
    return out


@contextlib.asynccontextmanager
async def page(journal: Path) -> AsyncIterator[TestClient[Any, Any]]:
    client: TestClient[Any, Any] = await webkit.client_for(
        Sources(socket=journal.parent / "none.sock", journal=journal)
    )
    try:
        yield client
    finally:
        await client.close()


async def _get(client: TestClient[Any, Any], path: str, status: int = 200) -> bytes:
    response = await client.get(path)
    body = await response.read()
    assert response.status == status, (path, response.status, body[:300])
    return body


def _copy(source: Path, target: Path) -> Path:
    target.write_bytes(source.read_bytes())
    return target


def _made(where: Path, pattern: str) -> list[Path]:
    return list(where.glob(pattern))


def _rows(text: str) -> list[list[str]]:
    return list(csv.reader(line for line in io.StringIO(text) if not line.startswith("#")))


async def test_a_lines_survey_gives_the_map_commands_files_and_its_view(
    journal: Path, commands: Path
) -> None:
    netcdf4 = pytest.importorskip("netCDF4")
    rasterio = pytest.importorskip("rasterio")
    async with page(journal) as client:
        doc = json.loads(await _get(client, f"/api/surveys/{LINES}/science"))
        bed = doc["map"]
        assert "why" not in bed, bed
        assert bed["figures"]["cv_rmse_m"] > 0 and bed["contours"] and bed["cells"]
        assert bed["files"] == ["bathymetry.nc", "contours.geojson", "depth.tif", "hypsography.csv"]
        # The contours on the page are the file's; the file is the command's.
        contours = json.loads(await _get(client, f"/download/survey/{LINES}/contours.geojson"))
        assert [f["geometry"]["coordinates"] for f in contours["features"]] == [
            c["lines"] for c in bed["contours"]
        ]
        written = json.loads((commands / "map" / "contours.geojson").read_text())
        assert contours["features"] == written["features"]
        table = (await _get(client, f"/download/survey/{LINES}/hypsography.csv")).decode()
        assert _rows(table) == _rows((commands / "map" / "hypsography.csv").read_text())
        grid = await _get(client, f"/download/survey/{LINES}/bathymetry.nc")
        with (
            netcdf4.Dataset("grid.nc", memory=grid) as nc,
            netcdf4.Dataset(commands / "map" / "bathymetry.nc") as theirs,
        ):
            assert (nc["depth"][:] == theirs["depth"][:]).all()
        tif = await _get(client, f"/download/survey/{LINES}/depth.tif")
        with rasterio.MemoryFile(tif) as memory, memory.open() as image:
            assert image.crs is not None and image.read(1).size > 0
        _blocks_are_the_grids(journal, bed["cells"])
        # No sonde in this survey: its profiles say so, and their files are refused.
        assert "why" in doc["profiles"], doc["profiles"]
        refused = (await _get(client, f"/download/survey/{LINES}/stations.csv", 404)).decode()
        assert "no stations.csv" in refused


def _blocks_are_the_grids(journal: Path, cells: dict[str, Any]) -> None:
    """The page's shaded blocks: each the mean of its cells of the grid, and each corner
    where the projection puts it (the affine description: 1.4 mm off at 130 m)."""
    import numpy as np
    from pyproj import Transformer

    from cc_daemon.export.bathymap import MapOptions, make_map

    with JournalReader(journal) as reader:
        made = make_map(reader, reader.select_survey(LINES), MapOptions())
    grid, step = made.bed.grid, cells["step"]
    assert (cells["ny"], cells["nx"]) == grid.depth_m.shape
    for bj, row in enumerate(cells["depths"]):
        for bi, value in enumerate(row):
            block = grid.depth_m[bj * step : (bj + 1) * step, bi * step : (bi + 1) * step]
            mapped = block[np.isfinite(block)]
            assert value == (round(float(mapped.mean()), 2) if mapped.size else None)
    back = Transformer.from_crs(made.soundings.crs, "EPSG:4326", always_xy=True)
    half, (nx, ny) = made.bed.cell_m / 2, (cells["nx"], cells["ny"])
    for i, j in ((0, 0), (nx, ny), (nx // 2, ny)):
        x = grid.spec.x[0] - half + i * made.bed.cell_m
        y = grid.spec.y[0] - half + j * made.bed.cell_m
        lon, lat = back.transform(x, y)
        o, di, dj = cells["origin"], cells["di"], cells["dj"]
        assert abs(o[0] + i * di[0] + j * dj[0] - lon) < 1e-7  # about a centimetre
        assert abs(o[1] + i * di[1] + j * dj[1] - lat) < 1e-7


async def test_a_survey_of_casts_gives_the_profiles_commands_numbers(
    journal: Path, commands: Path
) -> None:
    netcdf4 = pytest.importorskip("netCDF4")
    async with page(journal) as client:
        doc = json.loads(await _get(client, f"/api/surveys/{CASTS}/science"))
        p = doc["profiles"]
        assert "why" not in p, p
        stations = (await _get(client, f"/download/survey/{CASTS}/stations.csv")).decode()
        theirs = _rows((commands / "profiles" / "stations.csv").read_text())
        assert _rows(stations) == theirs
        # The page's table is the file's, numbers as numbers and empty cells as null.
        assert p["stations"]["header"] == theirs[0]
        for mine, row in zip(p["stations"]["rows"], theirs[1:], strict=True):
            for value, text in zip(mine, row, strict=True):
                assert value == (None if text == "" else science._number(text))
        thermocline = theirs[0].index("thermocline [m]")
        assert all(isinstance(r[thermocline], float) for r in p["stations"]["rows"])
        # Each cast's binned profile: the way down and the way up, from profiles.csv.
        profiles = (await _get(client, f"/download/survey/{CASTS}/profiles.csv")).decode()
        assert _rows(profiles) == _rows((commands / "profiles" / "profiles.csv").read_text())
        # What was binned, per cast: the page overlays the bins only on as many readings.
        with JournalReader(journal) as reader:
            reader.select_survey(CASTS)
            samples = reader.sonde_samples()
        assert p["readings"] == {
            str(c): sum(s.cast_id == c for s in samples) for c in {s.cast_id for s in samples}
        }
        for cast in p["binned"].values():
            assert cast["temperature"]["down"] and cast["temperature"]["up"]
            depths = [d for _, d, _ in cast["temperature"]["down"]]
            assert depths == sorted(depths)
        nc = await _get(client, f"/download/survey/{CASTS}/profiles.nc")
        with netcdf4.Dataset("profiles.nc", memory=nc) as ds:
            assert ds.featureType == "profile"
        geo = json.loads(await _get(client, f"/download/survey/{CASTS}/stations.geojson"))
        assert len(geo["features"]) == len(p["stations"]["rows"])
        # No soundings in this survey: the map says why, and its files are refused.
        assert "nothing to map" in doc["map"]["why"] or "sounding" in doc["map"]["why"]
        await _get(client, f"/download/survey/{CASTS}/depth.tif", 404)


async def test_a_survey_is_made_again_only_when_its_journal_changed_and_fresh_s_passed(
    journal: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    db = _copy(journal, tmp_path / "copy.db")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(science, "FRESH_S", 1e9)  # never due: however slow the machine
    monkeypatch.setattr(science, "KEPT", 2)
    async with page(db) as client:
        first = json.loads(await _get(client, f"/api/surveys/{CASTS}/science"))
        (made,) = _made(tmp_path, "cc-daemon-web-science-*/survey-*")
        assert first["current"] and first["due_wall_s"] >= first["made_wall_s"]
        again = json.loads(await _get(client, f"/api/surveys/{CASTS}/science"))
        assert again["made_wall_s"] == first["made_wall_s"]  # unchanged: kept
        write_journal(db, [CastSpec(seed=3)])  # the journal grows (a third survey)
        again = json.loads(await _get(client, f"/api/surveys/{CASTS}/science"))
        assert again["made_wall_s"] == first["made_wall_s"]  # not due yet: kept
        assert not again["current"]  # and said: the page asks again when it is due
        monkeypatch.setattr(science, "FRESH_S", 0.0)
        monkeypatch.setattr(science, "COST_FACTOR", 0.0)
        again = json.loads(await _get(client, f"/api/surveys/{CASTS}/science"))
        assert again["made_wall_s"] > first["made_wall_s"]
        assert not made.exists()  # the older making's files are gone
        # Unknown surveys and files are refused; at most KEPT surveys are kept.
        await _get(client, "/api/surveys/99/science", 404)
        await _get(client, f"/download/survey/{CASTS}/summary.txt", 404)
        await _get(client, f"/download/survey/{CASTS}/..%2Fcopy.db", 404)
        for survey in (LINES, 3):
            await _get(client, f"/api/surveys/{survey}/science")
        assert len(_made(tmp_path, "cc-daemon-web-science-*/survey-*")) == science.KEPT
    assert not _made(tmp_path, "cc-daemon-web-science-*")  # removed when the page stops


def test_a_fault_in_the_maps_code_leaves_the_profiles_made_and_says_so(
    journal: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from cc_daemon.export import bathymap

    def broken(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("a bug")

    monkeypatch.setattr(bathymap, "make_map", broken)
    doc = science.make(journal, CASTS, None, tmp_path / "made")
    assert "RuntimeError" in doc["map"]["why"], doc["map"]
    assert doc["profiles"]["stations"]["rows"]  # the profiles made all the same
