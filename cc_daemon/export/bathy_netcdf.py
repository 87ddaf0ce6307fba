"""The lake floor as a CF-1.8 NetCDF grid, with ACDD 1.3 metadata a data server can serve.

This module owns the grid's file: projected coordinates `x`, `y` (metres, the UTM
zone's) with a `grid_mapping` variable `crs` (pyproj's CF form of the CRS, and its
WKT), 2-D `lat` and `lon`, and on them the bed's depth below the water surface
(`_FillValue` where not mapped), its elevation above sea level when the water level
was given, each cell's distance to the nearest sounding and its count of soundings.
The global attributes follow ACDD 1.3 (title, summary, keywords, the creator and
the publisher from `[survey]`, the extent in space and time) and carry the map's
figures: the quality control's counts by reason, the cross-validated RMSE and
bias, the rules it was made by. The tests check it with the IOOS compliance
checker's CF 1.8 and ACDD 1.3 suites.

netCDF4 is the `netcdf` extra, imported when a file is written. It never reads the
journal and writes only the path it is given.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import numpy as np

from cc_daemon import __version__
from cc_daemon.export import OptionalDependencyError
from cc_daemon.export.bathymap import SurveyMap
from cc_daemon.export.mapsummary import accuracy
from cc_daemon.store.records import iso_utc

FILL = -9999.0
# The [survey] keys that make the ACDD record whole; empty ones are left out.
CREATOR_KEYS = ("creator_name", "creator_email", "creator_url", "institution", "project", "license")


def missing_metadata(survey_map: SurveyMap) -> list[str]:
    """The `[survey]` keys whose ACDD attributes the file will lack (empty in settings)."""
    settings = survey_map.options.survey
    return [f"survey.{key}" for key in CREATOR_KEYS if not getattr(settings, key)]


def _lat_lon(survey_map: SurveyMap) -> tuple[np.ndarray[Any, Any], np.ndarray[Any, Any]]:
    from pyproj import Transformer

    spec = survey_map.bed.grid.spec
    gx, gy = np.meshgrid(spec.x, spec.y)
    back = Transformer.from_crs(survey_map.soundings.crs, "EPSG:4326", always_xy=True)
    lon, lat = back.transform(gx, gy)
    return np.asarray(lat), np.asarray(lon)


def _duration(seconds: float) -> str:
    return f"PT{max(round(seconds), 0)}S"


def _authority(url: str) -> str:
    """A reverse-DNS naming authority from a web address (`https://lab.example.org` ->
    `org.example.lab`); empty without one."""
    host = urlparse(url).hostname or ""
    return ".".join(reversed(host.split("."))) if host else ""


def global_attributes(survey_map: SurveyMap, lat: Any, lon: Any) -> dict[str, Any]:
    """Every global attribute of the grid's file: CF's, ACDD 1.3's and the map's figures."""
    bed, survey, settings = survey_map.bed, survey_map.survey, survey_map.options.survey
    grid = bed.grid
    mapped = grid.depth_m[grid.mapped]
    created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    simulated = "SIMULATED data: " if survey_map.simulated else ""
    counts = survey_map.soundings.counts()
    kept = counts.pop("kept")
    start, end = survey.start_wall_s, survey.end_wall_s
    attrs: dict[str, Any] = {
        "Conventions": "CF-1.8, ACDD-1.3",
        "title": f"{simulated}Lake bed depth from single-beam soundings, survey {survey.id}",
        "summary": (
            f"{simulated}Depth of the lake bed below the water surface of the survey's day,"
            f" gridded at {bed.cell_m:g} m from {kept} single-beam echosounder soundings"
            f" (block median, then {bed.method} interpolation); cells farther than"
            f" {bed.max_distance_m:.1f} m from any sounding are left empty. Accuracy:"
            f" {accuracy(survey_map)}."
        ),
        "keywords": "bathymetry, lake, reservoir, hypsography, single-beam echosounder",
        "keywords_vocabulary": "GCMD Science Keywords",
        "id": f"cc-daemon-map-{iso_utc(start)[:19].replace(':', '')}-survey-{survey.id}",
        "history": f"{created} written by cc-daemon {__version__} map",
        "comment": (
            "Depths are echosounder distances plus each transducer's draft, not corrected"
            " for heave or the speed of sound. distance_to_sounding says how far each cell"
            " is from what was measured."
        ),
        "source": f"cc-daemon {__version__} survey journal {survey_map.source_file.name}",
        "date_created": created,
        "date_modified": created,
        "date_issued": created,
        "date_metadata_modified": created,
        "processing_level": "gridded, quality-controlled soundings (block median, interpolated)",
        "product_version": __version__,
        "standard_name_vocabulary": "CF Standard Name Table v93",
        "platform": "uncrewed surface vehicle (autonomous survey boat)",
        "platform_vocabulary": "GCMD Platform Keywords",
        "instrument": "single-beam echosounder",
        "instrument_vocabulary": "GCMD Instrument Keywords",
        "cdm_data_type": "Grid",
        "references": "cc-daemon docs/maps.md",
        "acknowledgement": "Soundings by the survey boat's echosounders, gridded by cc-daemon",
        "contributor_name": f"cc-daemon {__version__}",
        "contributor_role": "processor",
        "geospatial_lat_min": float(np.nanmin(lat)),
        "geospatial_lat_max": float(np.nanmax(lat)),
        "geospatial_lon_min": float(np.nanmin(lon)),
        "geospatial_lon_max": float(np.nanmax(lon)),
        "geospatial_lat_units": "degrees_north",
        "geospatial_lon_units": "degrees_east",
        "geospatial_lat_resolution": f"{bed.cell_m / 111_320.0:.7f} degrees",
        "geospatial_lon_resolution": (
            f"{bed.cell_m / (111_320.0 * np.cos(np.radians(np.nanmean(lat)))):.7f} degrees"
        ),
        "geospatial_bounds": (
            f"POLYGON (({np.nanmin(lat):.7f} {np.nanmin(lon):.7f},"
            f" {np.nanmin(lat):.7f} {np.nanmax(lon):.7f}, {np.nanmax(lat):.7f}"
            f" {np.nanmax(lon):.7f}, {np.nanmax(lat):.7f} {np.nanmin(lon):.7f},"
            f" {np.nanmin(lat):.7f} {np.nanmin(lon):.7f}))"
        ),
        "geospatial_bounds_crs": "EPSG:4326",
        "geospatial_bounds_vertical_crs": "EPSG:5831",  # instantaneous water level depth
        "geospatial_vertical_min": float(mapped.min()) if len(mapped) else 0.0,
        "geospatial_vertical_max": float(mapped.max()) if len(mapped) else 0.0,
        "geospatial_vertical_units": "m",
        "geospatial_vertical_positive": "down",
        "geospatial_vertical_resolution": "0.001 m",
        "time_coverage_start": iso_utc(start),
        "time_coverage_end": iso_utc(end),
        "time_coverage_duration": _duration(end - start),
        "time_coverage_resolution": _duration(end - start),
        # The map's own figures.
        "simulated": "yes" if survey_map.simulated else "no",
        "grid_cell_size_m": bed.cell_m,
        "grid_max_distance_m": bed.max_distance_m,
        "grid_interpolation": bed.method,
        "line_spacing_m": bed.spacing_m if bed.spacing_m is not None else "not found",
        "cv_rmse_m": bed.cv.rmse_m,
        "cv_bias_m": bed.cv.bias_m,
        "cv_raw_rmse_m": bed.cv.raw_rmse_m,
        "cv_block_m": bed.cv.block_m,
        "cv_folds": bed.cv.folds,
        "soundings_kept": kept,
        **{f"soundings_rejected_{reason}": n for reason, n in counts.items()},
        "autopilot_draft_m": settings.autopilot_draft_m,
        "onboard_draft_m": settings.onboard_draft_m,
    }
    if survey_map.options.water_level_m is not None:
        attrs["water_level_m_above_sea_level"] = survey_map.options.water_level_m
    for key in CREATOR_KEYS:
        value = getattr(settings, key)
        if value:
            attrs[key] = value
    if settings.creator_name:
        attrs["creator_type"] = "person"
        attrs["creator_institution"] = settings.institution or settings.creator_name
        attrs["publisher_name"] = settings.creator_name
        attrs["publisher_type"] = "person"
        attrs["publisher_institution"] = settings.institution or settings.creator_name
    if settings.creator_email:
        attrs["publisher_email"] = settings.creator_email
    if settings.creator_url:
        attrs["publisher_url"] = settings.creator_url
        attrs["metadata_link"] = settings.creator_url
        attrs["naming_authority"] = _authority(settings.creator_url)
    if settings.project:
        attrs["program"] = settings.project
    return attrs


def _layer(nc: Any, name: str, values: Any, dtype: str, attrs: dict[str, Any]) -> None:
    var = nc.createVariable(name, dtype, ("y", "x"), fill_value=attrs.pop("_FillValue", None))
    var.setncatts({"grid_mapping": "crs", "coordinates": "lat lon", **attrs})
    var[:] = values


def write(survey_map: SurveyMap, path: Path) -> None:
    """Write the map's grid to `path` (NETCDF4_CLASSIC)."""
    try:
        import netCDF4
    except ImportError as exc:
        raise OptionalDependencyError("the NetCDF grid", "netCDF4", "netcdf") from exc
    grid = survey_map.bed.grid
    spec = grid.spec
    lat, lon = _lat_lon(survey_map)
    depth = np.where(grid.mapped, np.round(grid.depth_m, 3), FILL)
    with netCDF4.Dataset(str(path), "w", format="NETCDF4_CLASSIC") as nc:
        nc.setncatts(global_attributes(survey_map, lat, lon))
        nc.createDimension("y", spec.ny)
        nc.createDimension("x", spec.nx)
        x = nc.createVariable("x", "f8", ("x",))
        x.setncatts(
            {"standard_name": "projection_x_coordinate", "long_name": "UTM easting of the"
             " cell's centre", "units": "m", "axis": "X"}
        )  # fmt: skip
        x[:] = spec.x
        y = nc.createVariable("y", "f8", ("y",))
        y.setncatts(
            {"standard_name": "projection_y_coordinate", "long_name": "UTM northing of the"
             " cell's centre", "units": "m", "axis": "Y"}
        )  # fmt: skip
        y[:] = spec.y
        crs = nc.createVariable("crs", "i4")
        cf = survey_map.soundings.crs.to_cf()
        crs.setncatts({k: v for k, v in cf.items() if v is not None})
        lat_var = nc.createVariable("lat", "f8", ("y", "x"))
        lat_var.setncatts(
            {"standard_name": "latitude", "long_name": "latitude", "units": "degrees_north"}
        )
        lat_var[:] = np.round(lat, 7)
        lon_var = nc.createVariable("lon", "f8", ("y", "x"))
        lon_var.setncatts(
            {"standard_name": "longitude", "long_name": "longitude", "units": "degrees_east"}
        )
        lon_var[:] = np.round(lon, 7)
        _layer(nc, "depth", depth, "f4", {
            "_FillValue": FILL,
            "standard_name": "sea_floor_depth_below_sea_surface",
            "long_name": "depth of the lake bed below the water surface of the survey's day",
            "units": "m",
            "positive": "down",
            "coverage_content_type": "modelResult",
        })  # fmt: skip
        elevation = survey_map.elevation_m()
        if elevation is not None:
            _layer(nc, "bed_elevation", np.where(grid.mapped, np.round(elevation, 3), FILL),
                   "f4", {
                "_FillValue": FILL,
                "standard_name": "surface_altitude",
                "long_name": "elevation of the lake bed above sea level (the water level of"
                " the day less the depth)",
                "units": "m",
                "coverage_content_type": "modelResult",
            })  # fmt: skip
        _layer(nc, "distance_to_sounding", np.round(grid.distance_m, 2), "f4", {
            "long_name": "distance from the cell's centre to the nearest sounding kept",
            "units": "m",
            "coverage_content_type": "qualityInformation",
        })  # fmt: skip
        _layer(nc, "soundings", grid.count.astype(np.int32), "i4", {
            "long_name": "soundings kept in the cell",
            "standard_name": "number_of_observations",
            "units": "1",
            "coverage_content_type": "auxiliaryInformation",
        })  # fmt: skip
