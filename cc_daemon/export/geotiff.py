"""The lake floor's depth as a GeoTIFF with its CRS: what QGIS and GDAL open as they are.

This module owns the GeoTIFF: one band of 32-bit floats (the depth below the water
surface, metres; -9999, GDAL's no-data tag, where not mapped), north up, its
cells placed by the model tie point and pixel scale tags, its CRS the UTM zone's
EPSG code in the GeoKey directory (a projected CRS, metres, pixels as areas). It
is written with tifffile (pure Python, 2 MB installed) rather than rasterio (GDAL
with it, about 110 MB), which the tests use to read it back. It never reads the
journal and writes only the path it is given.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cc_daemon.export import OptionalDependencyError
from cc_daemon.export.bathymap import SurveyMap

NODATA = -9999.0
_MODEL_PIXEL_SCALE = 33550
_MODEL_TIEPOINT = 33922
_GEO_KEY_DIRECTORY = 34735
_GDAL_NODATA = 42113
_PROJECTED, _PIXEL_IS_AREA, _METRE = 1, 1, 9001


def geokeys(epsg: int) -> tuple[int, ...]:
    """The GeoKey directory of a projected CRS known by its EPSG code (GeoTIFF 1.0)."""
    keys = (
        (1024, 0, 1, _PROJECTED),  # GTModelTypeGeoKey
        (1025, 0, 1, _PIXEL_IS_AREA),  # GTRasterTypeGeoKey
        (3072, 0, 1, epsg),  # ProjectedCSTypeGeoKey
        (3076, 0, 1, _METRE),  # ProjLinearUnitsGeoKey
    )
    return (1, 1, 0, len(keys), *(v for key in keys for v in key))


def write(survey_map: SurveyMap, path: Path) -> None:
    """Write the map's depth grid to `path` as a GeoTIFF."""
    try:
        import tifffile
    except ImportError as exc:
        raise OptionalDependencyError("the GeoTIFF", "tifffile", "science") from exc
    grid = survey_map.bed.grid
    spec = grid.spec
    if survey_map.epsg == 0:
        raise ValueError(f"the map's CRS {survey_map.soundings.crs.name} has no EPSG code")
    # Row 0 of a TIFF is its top: the northernmost row of cells.
    band = np.where(grid.mapped, grid.depth_m, NODATA).astype(np.float32)[::-1]
    top = spec.y0 + spec.ny * spec.cell_m
    keys = geokeys(survey_map.epsg)
    tifffile.imwrite(
        path,
        np.ascontiguousarray(band),
        photometric="minisblack",
        metadata=None,
        extratags=[
            (_MODEL_PIXEL_SCALE, "d", 3, (spec.cell_m, spec.cell_m, 0.0), True),
            (_MODEL_TIEPOINT, "d", 6, (0.0, 0.0, 0.0, spec.x0, top, 0.0), True),
            (_GEO_KEY_DIRECTORY, "H", len(keys), keys, True),
            (_GDAL_NODATA, "s", 0, f"{NODATA:g}", True),
        ],
    )
