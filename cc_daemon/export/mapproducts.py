"""Every product of a survey's map, written into one directory.

This module owns the directory `cc-daemon map -o DIR` fills, and its file names:
`bathymetry.nc` (CF-1.8 and ACDD 1.3), `depth.tif` (GeoTIFF), `contours.geojson`
(RFC 7946), `hypsography.csv` (`depth_m,area_m2,volume_m3`), `map.png` and
`summary.txt` with `summary.json`. Each is written to a temporary name beside
its place and renamed into it once whole, so a reader never opens half a file.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

from cc_daemon.export import bathy_csv, bathy_netcdf, bathyplot, contours_geojson, geotiff
from cc_daemon.export.bathymap import SurveyMap
from cc_daemon.export.mapsummary import figures, finite, text

NAMES = {
    "grid": "bathymetry.nc",
    "geotiff": "depth.tif",
    "contours": "contours.geojson",
    "hypsography": "hypsography.csv",
    "map": "map.png",
    "summary": "summary.txt",
    "figures": "summary.json",
}


def _atomic(path: Path, write: Callable[[Path], object]) -> None:
    partial = path.with_name(f".{path.name}.partial")
    try:
        write(partial)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def _text(content: str) -> Callable[[Path], object]:
    return lambda p: p.write_text(content, encoding="utf-8")


def write_all(survey_map: SurveyMap, directory: Path) -> dict[str, Path]:
    """Write every product into `directory` (made if missing); return them by kind."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = {kind: directory / name for kind, name in NAMES.items()}
    found = contours_geojson.map_contours(survey_map)
    _atomic(paths["grid"], lambda p: bathy_netcdf.write(survey_map, p))
    _atomic(paths["geotiff"], lambda p: geotiff.write(survey_map, p))

    def contours(p: Path) -> None:
        with p.open("w", encoding="utf-8") as out:
            contours_geojson.write(survey_map, found, out)

    _atomic(paths["contours"], contours)
    hyps = survey_map.bed.hypsography
    if hyps is not None:

        def table(p: Path) -> None:
            with p.open("w", encoding="utf-8", newline="") as out:
                bathy_csv.write(hyps, out)

        _atomic(paths["hypsography"], table)
    else:
        del paths["hypsography"]
    _atomic(paths["map"], lambda p: bathyplot.write(survey_map, found, p))
    _atomic(paths["summary"], _text(text(survey_map)))
    _atomic(paths["figures"], _text(json.dumps(finite(figures(survey_map)), indent=2) + "\n"))
    return paths
