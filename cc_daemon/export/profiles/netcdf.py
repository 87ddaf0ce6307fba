"""The binned profiles as CF NetCDF: one profile per cast and way, on the survey's bins.

This module owns the layout of `profiles.nc`: CF-1.8 `featureType = "profile"` in
the orthogonal multidimensional representation (CF 9.3.1: every profile shares
the `depth` coordinate, the bins' centres), a profile per cast and way (`way`:
down, up) with the cast's start `time`, `lat` and `lon`; per parameter P its value
at each bin's centre (`P`, with its CF standard name where the map gives one) and,
as its ancillary variables, the readings' mean (`P_mean`), standard deviation
(`P_sd`), count (`P_count`) and flag (`P_flag`: good, few readings, none); the
mean depth of each bin's readings (`readings_depth`). A missing value is the fill
value (NaN), never zero. The IOOS compliance checker's CF 1.8 suite judges it in
the tests. netCDF4 is imported when the file is written; it never reads the journal.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from cc_daemon.export import OptionalDependencyError
from cc_daemon.export.netcdf import TIME_UNITS, profile_globals
from cc_daemon.export.profiles.survey import Survey
from cc_daemon.export.profiles.tables import WAYS, provenance_line, readings_depth, way
from cc_daemon.export.provenance import of_casts
from cc_daemon.export.sonde_netcdf import CF_UNITS

FLAGS = ("good", "few_readings", "no_readings")
# UDUNITS spellings beyond the sonde export's: relative fluorescence is a ratio, and the
# sonde's own unit goes in `sonde_units` (the CF checker holds these files to UDUNITS).
_MORE_UNITS = {"RFU": "1", "uS/cm": "uS cm-1", "mS/cm": "mS cm-1"}


def cf_unit(unit: str) -> str:
    return CF_UNITS.get(unit) or _MORE_UNITS.get(unit) or unit or "1"


def write(survey: Survey, path: Path) -> int:
    """Write the survey's binned profiles to `path`; return the number of profiles."""
    try:
        import netCDF4
        import numpy as np
    except ImportError as exc:
        raise OptionalDependencyError("NetCDF export", "netCDF4", "netcdf") from exc
    rows = [(cast, name) for cast in survey.casts for name in WAYS]
    if not rows:
        raise ValueError("no profiles to write")
    depths = survey.casts[0].processed.down.depth_m
    with netCDF4.Dataset(str(path), "w", format="NETCDF4_CLASSIC") as nc:
        profile_globals(
            nc, "Binned water-quality profiles of an autonomous survey boat's sonde", "profiles"
        )
        made = of_casts([c.cast for c in survey.casts])
        nc.winch_backend = made.winch_backend
        nc.simulated = made.simulated
        nc.processing = provenance_line(survey).removeprefix("# ")
        nc.comment = (
            "One profile per cast and way (way: down, up). Each value is the bin's mean moved"
            " to the bin's centre along the profile's gradient; P_mean is the plain mean of"
            " the bin's readings. Sensor lags corrected before binning (processing)."
            + (" SIMULATED DATA: read from the simulated sonde." if survey.simulated else "")
        )
        nc.createDimension("profile", len(rows))
        nc.createDimension("depth", len(depths))

        def var(name: str, kind: str, dims: tuple[str, ...], **attrs: Any) -> Any:
            fill = attrs.pop("_FillValue", None)
            variable = nc.createVariable(name, kind, dims, fill_value=fill)
            variable.setncatts(attrs)
            return variable

        var("profile", "i4", ("profile",), cf_role="profile_id", long_name="profile number")[:] = (
            np.arange(len(rows))
        )
        var("cast_id", "i4", ("profile",), long_name="cast id in the journal")[:] = [
            c.cast.id for c, _ in rows
        ]
        var(
            "way",
            "i1",
            ("profile",),
            long_name="way of the cast",
            flag_values=np.array([0, 1], dtype="i1"),
            flag_meanings="down up",
        )[:] = [WAYS.index(name) for _, name in rows]
        var(
            "time",
            "f8",
            ("profile",),
            standard_name="time",
            long_name="start of the cast",
            units=TIME_UNITS,
            calendar="standard",
            axis="T",
        )[:] = [round(c.cast.start_wall_s, 3) for c, _ in rows]
        var(
            "lat",
            "f8",
            ("profile",),
            standard_name="latitude",
            long_name="station latitude",
            units="degrees_north",
            axis="Y",
        )[:] = [round(c.cast.lat_deg, 7) for c, _ in rows]
        var(
            "lon",
            "f8",
            ("profile",),
            standard_name="longitude",
            long_name="station longitude",
            units="degrees_east",
            axis="X",
        )[:] = [round(c.cast.lon_deg, 7) for c, _ in rows]
        var(
            "depth",
            "f8",
            ("depth",),
            standard_name="depth",
            long_name="depth of the bin's centre",
            units="m",
            positive="down",
            axis="Z",
        )[:] = depths
        var(
            "readings_depth",
            "f8",
            ("profile", "depth"),
            _FillValue=math.nan,
            long_name="mean depth of the bin's readings",
            units="m",
            coordinates="time lat lon depth",
        )[:] = np.array([readings_depth(c, name, survey.settings.bin_m) for c, name in rows])
        for c in survey.columns:
            profiles = [way(cast, name) for cast, name in rows]
            unit = cf_unit(c.unit)
            where = "time lat lon depth"
            attrs: dict[str, Any] = {
                "_FillValue": math.nan,
                "long_name": f"{c.long_name} at the bin's centre",
                "units": unit,
                "coordinates": where,
                "ancillary_variables": " ".join(
                    f"{c.name}_{s}" for s in ("mean", "sd", "count", "flag")
                ),
            }
            if c.standard_name:
                attrs["standard_name"] = c.standard_name
            if unit != c.unit:
                attrs["sonde_units"] = c.unit
            var(c.name, "f4", ("profile", "depth"), **attrs)[:] = np.array(
                [p.value[c.name] for p in profiles]
            )
            for suffix, what, method in (
                ("mean", "mean", "mean"),
                ("sd", "standard deviation", "standard_deviation"),
            ):
                statistic = [p.mean if suffix == "mean" else p.std for p in profiles]
                var(
                    f"{c.name}_{suffix}",
                    "f4",
                    ("profile", "depth"),
                    _FillValue=math.nan,
                    long_name=f"{c.long_name}, {what} of the bin's readings",
                    units=unit,
                    coordinates=where,
                    cell_methods=f"depth: {method}",
                )[:] = np.array([values[c.name] for values in statistic])
            var(
                f"{c.name}_count",
                "i4",
                ("profile", "depth"),
                standard_name="number_of_observations",
                units="1",
                long_name=f"readings of {c.name} in the bin",
                coordinates=where,
            )[:] = np.array([p.count[c.name] for p in profiles])
            var(
                f"{c.name}_flag",
                "i1",
                ("profile", "depth"),
                long_name=f"{c.name} bin quality",
                flag_values=np.arange(len(FLAGS), dtype="i1"),
                flag_meanings=" ".join(FLAGS),
                comment=f"few_readings: under {survey.settings.min_count} readings",
                coordinates=where,
            )[:] = np.array(
                [np.where(p.count[c.name] == 0, 2, np.where(p.few[c.name], 1, 0)) for p in profiles]
            )
    return len(rows)
