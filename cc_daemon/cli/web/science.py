"""The day's science on the field page: a survey's lake floor and its profiles.

Made by the same code, and written as the same files, as `cc-daemon map` and
`cc-daemon profiles` with their defaults: the files go into a directory of the
page's own (`map/`, `profiles/`), from which they are downloaded, and the page's
JSON is read back from them (the stations table and the binned profiles as the
CSV files hold them, the contours as the GeoJSON does), so the page never shows
a number the files do not. A survey is made once, then again when its journal
has changed and the last making is older than FRESH_S or COST_FACTOR times what
it took, whichever is longer: a growing survey's science costs the page at most
a twentieth of one core (a twelve-hour day takes 11 s on a laptop, a minute on
a Pi: made again every 4 or 20 minutes while it grows). One making at a time,
on a thread of its own; KEPT surveys are kept, the oldest removed; everything is
removed when the page stops.
"""

from __future__ import annotations

import asyncio
import csv
import math
import os
import shutil
import tempfile
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog

from cc_daemon.cli.web.journaldata import NotFound, _clean, _open, undamaged_survey
from cc_daemon.export import OptionalDependencyError
from cc_daemon.store import StoreError

if TYPE_CHECKING:
    from cc_daemon.config.survey import SurveySettings
    from cc_daemon.export.bathymap import SurveyMap

log = structlog.get_logger(__name__)

FRESH_S = 10.0
COST_FACTOR = 20.0
KEPT = 4
CELLS_ACROSS = 48  # the page's shaded depths: at most this many cells a side
# Each download, by the name the command gives it: its directory and media type.
PRODUCTS = {
    "bathymetry.nc": ("map", "application/x-netcdf"),
    "depth.tif": ("map", "image/tiff"),
    "contours.geojson": ("map", "application/geo+json"),
    "hypsography.csv": ("map", "text/csv; charset=utf-8"),
    "profiles.nc": ("profiles", "application/x-netcdf"),
    "profiles.csv": ("profiles", "text/csv; charset=utf-8"),
    "stations.csv": ("profiles", "text/csv; charset=utf-8"),
    "stations.geojson": ("profiles", "application/geo+json"),
}
MISSING_LIBRARY = "{name} is not installed where the page runs (the 'science' extra: {what})"


@dataclass(frozen=True, slots=True)
class Made:
    signature: tuple[int, ...]  # the journal's files' sizes and times when made
    at_s: float  # monotonic, when made
    took_s: float
    directory: Path
    doc: dict[str, Any]


def signature(journal: Path) -> tuple[int, ...]:
    """What changes when the journal is written: its file's and its WAL's size and time."""
    found: list[int] = []
    for path in (journal, journal.with_name(journal.name + "-wal")):
        try:
            st = path.stat()
        except OSError:
            found += [-1, -1]
        else:
            found += [st.st_size, st.st_mtime_ns]
    return tuple(found)


class Science:
    """Each survey's science, made when asked and kept (see the module's docstring)."""

    def __init__(self, journal: Path, settings: SurveySettings | None = None) -> None:
        self._journal = journal
        self._settings = settings
        self._root: Path | None = None
        self._made: OrderedDict[int, Made] = OrderedDict()
        self._lock = asyncio.Lock()
        self._thread = ThreadPoolExecutor(1, thread_name_prefix="science")
        self._count = 0

    async def get(self, survey: int) -> Made:
        async with self._lock:
            kept = self._made.get(survey)
            now = signature(self._journal)
            if kept is not None and (kept.signature == now or time.monotonic() < _due(kept)):
                self._made.move_to_end(survey)
                return kept
            if self._root is None:
                self._root = Path(tempfile.mkdtemp(prefix="cc-daemon-web-science-"))
            self._count += 1
            directory = self._root / f"survey-{survey}-{self._count}"
            loop = asyncio.get_running_loop()
            began = time.monotonic()
            try:
                doc = await loop.run_in_executor(
                    self._thread, make, self._journal, survey, self._settings, directory
                )
            except BaseException:
                await loop.run_in_executor(self._thread, _remove, directory)
                raise
            made = Made(now, time.monotonic(), time.monotonic() - began, directory, doc)
            self._made[survey] = made
            self._made.move_to_end(survey)
            gone = [kept.directory] if kept is not None else []
            while len(self._made) > KEPT:
                gone.append(self._made.popitem(last=False)[1].directory)
            for path in gone:  # a download of an old file holds it open: Unix lets it finish
                await loop.run_in_executor(self._thread, _remove, path)
            return made

    def state(self, made: Made) -> dict[str, Any]:
        """Whether the journal has changed since `made` (`current`), and when a changed
        journal's survey is made again (`due_wall_s`): for the page to ask again then."""
        due = time.time() + _due(made) - time.monotonic()
        return {"current": signature(self._journal) == made.signature, "due_wall_s": due}

    def close(self) -> None:
        self._thread.shutdown(wait=True, cancel_futures=True)
        if self._root is not None:
            _remove(self._root)


def _due(made: Made) -> float:
    """When a changed journal's survey is made again (monotonic)."""
    return made.at_s + max(FRESH_S, COST_FACTOR * made.took_s)


def _remove(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


def make(
    journal: Path, survey: int, settings: SurveySettings | None, directory: Path
) -> dict[str, Any]:
    """Survey `survey`'s map and profiles into `directory` (`map/`, `profiles/`), and the
    page's JSON of them. NotFound: no such survey; StoreError: an unreadable journal."""
    directory.mkdir(parents=True)
    made_at = time.time()
    lake = None
    try:
        survey_map = _survey_map(journal, survey, settings)
    except ImportError as exc:
        bed: dict[str, Any] = {"why": MISSING_LIBRARY.format(name=exc.name, what="the map")}
    except ValueError as exc:
        bed = {"why": str(exc)}
    except (NotFound, StoreError):
        raise
    except Exception as exc:  # a fault of the map's own code: the profiles still made
        log.error("the day's map could not be made", survey=survey, exc_info=exc)
        bed = {"why": f"the map could not be made ({type(exc).__name__}: see the page's log)"}
    else:
        from cc_daemon.export.bathymap import trusted_hypsography

        bed = _bed(survey_map, directory / "map")
        lake, why = trusted_hypsography(survey_map)
        if lake is None:
            bed["schmidt_why"] = why
    profiles = _profiles(journal, survey, lake, directory / "profiles")
    return _clean({"survey": survey, "made_wall_s": made_at, "map": bed, "profiles": profiles})  # type: ignore[no-any-return]


def _survey_map(journal: Path, survey: int, settings: SurveySettings | None) -> SurveyMap:
    from cc_daemon.export.bathymap import MapOptions, make_map

    options = MapOptions() if settings is None else MapOptions(survey=settings)
    with _open(journal) as reader:
        chosen = undamaged_survey(reader, survey)
        if chosen is None:
            raise NotFound(f"no survey {survey}")
        return make_map(reader, chosen, options)


def _write_each(directory: Path, writers: dict[str, Callable[[Path], object]]) -> list[str]:
    """Write each file (to a temporary name, renamed once whole); the ones that could not
    be written for a missing library are said, the others written all the same."""
    directory.mkdir(parents=True, exist_ok=True)
    notes = []
    for name, write in writers.items():
        partial = directory / f".{name}.partial"
        try:
            write(partial)
            os.replace(partial, directory / name)
        except (ImportError, OptionalDependencyError) as exc:
            what = getattr(exc, "name", None) or str(exc)
            notes.append(f"{name} not written: {what} is not installed where the page runs")
        finally:
            partial.unlink(missing_ok=True)
    return notes


def _bed(survey_map: SurveyMap, directory: Path) -> dict[str, Any]:
    """The map's files (as `cc-daemon map` writes them) and the page's view of it: its
    figures, its contours and shaded cells in longitude and latitude."""
    from cc_daemon.export import bathy_csv, bathy_netcdf, contours_geojson, geotiff
    from cc_daemon.export.mapsummary import figures

    found = contours_geojson.map_contours(survey_map)
    collection = contours_geojson.feature_collection(survey_map, found)
    hyps = survey_map.bed.hypsography

    def contours(p: Path) -> None:
        with p.open("w", encoding="utf-8") as out:
            contours_geojson.write(survey_map, found, out)

    def table(p: Path) -> None:
        assert hyps is not None
        with p.open("w", encoding="utf-8", newline="") as out:
            bathy_csv.write(hyps, out)

    writers: dict[str, Callable[[Path], object]] = {
        "bathymetry.nc": lambda p: bathy_netcdf.write(survey_map, p),
        "depth.tif": lambda p: geotiff.write(survey_map, p),
        "contours.geojson": contours,
    }
    if hyps is not None:
        writers["hypsography.csv"] = table
    notes = _write_each(directory, writers)
    return {
        "figures": figures(survey_map),
        "files": sorted(p.name for p in directory.iterdir() if not p.name.startswith(".")),
        "notes": notes,
        "contours": [
            {"depth_m": f["properties"]["depth_m"], "lines": f["geometry"]["coordinates"]}
            for f in collection["features"]
        ],
        "cells": _cells(survey_map),
    }


def _cells(survey_map: SurveyMap) -> dict[str, Any]:
    """The grid's depths averaged over blocks of `step` cells a side (at most CELLS_ACROSS
    blocks a side), row by row from the south-west (null: no cell of the block mapped),
    and where a cell's corner is: `origin` (the south-west corner of the grid's first
    cell) plus `i` times `di` plus `j` times `dj`, in longitude and latitude, for cell
    corner (i, j). The projection is not quite affine (1.4 mm off at 130 m from the
    origin, growing with the square of the distance: metres at 5 km, under a pixel of
    the page's map), and 2,304 blocks cost about 12 kB where their corners cost 200 kB."""
    import numpy as np
    from pyproj import Transformer

    grid = survey_map.bed.grid
    x, y, depth = grid.spec.x, grid.spec.y, grid.depth_m
    step = max(1, math.ceil(max(len(x), len(y)) / CELLS_ACROSS))
    cell = survey_map.bed.cell_m
    back = Transformer.from_crs(survey_map.soundings.crs, "EPSG:4326", always_xy=True)
    x0, y0 = float(x[0]) - cell / 2, float(y[0]) - cell / 2
    lon, lat = back.transform([x0, x0 + cell * len(x), x0], [y0, y0, y0 + cell * len(y)])
    rows = []
    for j in range(0, len(y), step):
        row = []
        for i in range(0, len(x), step):
            block = depth[j : j + step, i : i + step]
            found = np.isfinite(block).any()
            row.append(round(float(np.nanmean(block)), 2) if found else None)
        rows.append(row)
    return {
        "step": step,
        "nx": len(x),
        "ny": len(y),
        "origin": [float(lon[0]), float(lat[0])],
        "di": [float(lon[1] - lon[0]) / len(x), float(lat[1] - lat[0]) / len(x)],
        "dj": [float(lon[2] - lon[0]) / len(y), float(lat[2] - lat[0]) / len(y)],
        "depths": rows,
    }


def _profiles(journal: Path, survey: int, lake: Any, directory: Path) -> dict[str, Any]:
    """The survey's profiles (as `cc-daemon profiles` writes them) and the page's view:
    the stations table and each cast's binned profiles, read back from the CSV files."""
    try:
        from cc_daemon.cli.profiles import write_tables
        from cc_daemon.export.profiles.survey import profile_survey
    except ImportError as exc:
        return {"why": MISSING_LIBRARY.format(name=exc.name, what="the profiles")}
    with _open(journal) as reader:
        undamaged_survey(reader, survey)
        casts = reader.casts()
        samples = reader.sonde_samples()
        happened = reader.events()
    try:
        made = profile_survey(casts, samples, happened, lake=lake)
    except ValueError as exc:
        return {"why": str(exc)}
    directory.mkdir(parents=True, exist_ok=True)
    said: list[str] = []
    write_tables(made, directory, said.append)
    notes = [*made.notes, *(line for line in said if "not written" in line)]
    return {
        "bin_m": made.settings.bin_m,
        "lag_correction": made.settings.method,  # inverse, shift or none
        "lags_s": {name: t for name, t in made.settings.response_s.items() if t > 0},
        "readings": _per_cast(samples),  # what was binned: the page's own count may be newer
        "notes": notes,
        "files": sorted(p.name for p in directory.iterdir() if not p.name.startswith(".")),
        "stations": _rows(directory / "stations.csv"),
        "binned": _binned(_rows(directory / "profiles.csv")),
    }


def _per_cast(samples: list[Any]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for sample in samples:
        if sample.cast_id is not None:
            counts[str(sample.cast_id)] = counts.get(str(sample.cast_id), 0) + 1
    return counts


def _number(text: str) -> Any:
    if text == "":
        return None
    try:
        value = float(text)
    except ValueError:
        return text
    return value if math.isfinite(value) else None


def _rows(path: Path) -> dict[str, Any]:
    """A CSV file the commands write: its `#` lines, its header and its rows, numbers
    read as numbers and empty cells as null."""
    with path.open(encoding="utf-8", newline="") as f:
        lines = [line for line in f if not line.startswith("#")]
    reader = csv.reader(lines)
    header = next(reader, [])
    return {"header": header, "rows": [[_number(c) for c in row] for row in reader]}


def _binned(table: dict[str, Any]) -> dict[str, Any]:
    """profiles.csv as each cast's way down and way up: per parameter, [value, depth]
    at each bin's centre, and whether the bin has too few readings (`few`)."""
    header: list[str] = table["header"]
    at = {name: i for i, name in enumerate(header)}
    names = [h for h in header if f"{h.split(' [')[0]}_flag" in at]
    out: dict[str, Any] = {}
    for row in table["rows"]:
        cast = out.setdefault(str(int(row[at["cast_id"]])), {})
        depth = row[at["depth [m]"]]
        for full in names:
            name = full.split(" [")[0]
            value, flag = row[at[full]], row[at[f"{name}_flag"]]
            if value is None or depth is None or flag == "empty":
                continue
            way = cast.setdefault(name, {"down": [], "up": []})[row[at["way"]]]
            way.append([value, depth, flag == "few"])
    return out
