"""NetCDF-CF export of the sonde's profiles: one profile per cast, one variable per parameter.

This module owns the layout of the sonde's NetCDF file: CF-1.8
`featureType = "profile"`, contiguous ragged array (CF 9.3.3) like the depth
export (`netcdf.py`): the cast's station (`time`, `lat`, `lon`) per profile,
the readings along `obs` with `row_size` saying how many belong to each. The
vertical coordinate `depth` is the sonde's own pressure depth where it read
one, else the winch's line out (`depth_source` says which); each parameter is
a float variable with `units`, `long_name` and its CF `standard_name` where
the map gives one; a missing value is the fill value (NaN), never zero.

netCDF4 is imported when a file is written. It never reads the journal.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from cc_daemon import __version__
from cc_daemon.export import OptionalDependencyError
from cc_daemon.export.netcdf import TIME_UNITS, profile_file
from cc_daemon.export.sonde import Column
from cc_daemon.store.records import CastRecord
from cc_daemon.store.sonde import SondeSampleRecord

PHASE_FLAGS = ("soaking", "descending", "dwelling", "ascending", "aborting", "stranded")
BYTE_FILL = -127
# UDUNITS spellings for the units a sonde map is likely to use.
CF_UNITS = {"%": "percent", "mg/L": "mg L-1", "ug/L": "ug L-1", "µg/L": "ug L-1"}


def _nan(value: float | None) -> float:
    return math.nan if value is None else value


def write(
    casts: Sequence[CastRecord],
    samples: Sequence[SondeSampleRecord],
    columns: Sequence[Column],
    path: Path,
) -> int:
    """Write the casts' sonde profiles to `path`; return the number of readings written."""
    try:
        import netCDF4
        import numpy as np
    except ImportError as exc:
        raise OptionalDependencyError("NetCDF export", "netCDF4", "netcdf") from exc
    order = {cast.id: index for index, cast in enumerate(casts)}
    kept = sorted(
        (s for s in samples if s.cast_id in order),
        key=lambda s: (order[s.cast_id or 0], s.mono_s),
    )
    if not kept:
        raise ValueError("no sonde readings in these casts")
    counts = Counter(s.cast_id for s in kept)

    with netCDF4.Dataset(str(path), "w", format="NETCDF4_CLASSIC") as nc:
        nc.Conventions = "CF-1.8"
        nc.featureType = "profile"
        nc.cdm_data_type = "Profile"
        nc.title = "Water-quality profiles of an autonomous survey boat's sonde"
        nc.source = f"cc-daemon {__version__} survey journal"
        nc.date_created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
        simulated = any(s.simulated for s in kept)
        nc.comment = (
            "One profile per cast. depth is the sonde's pressure depth, or the winch's"
            " line out where the sonde gave none (depth_source). Missing readings are"
            " NaN with their reason in the journal."
            + (" SIMULATED DATA: read from the simulated sonde." if simulated else "")
        )
        var = profile_file(nc, casts, counts, n_obs=len(kept), rows_are="readings")

        var(
            "obs_time",
            "f8",
            "obs",
            standard_name="time",
            long_name="time of the reading's request",
            units=TIME_UNITS,
            calendar="standard",
        )[:] = [s.wall_s for s in kept]
        depths = [s.sonde_depth_m if s.sonde_depth_m is not None else s.line_out_m for s in kept]
        var(
            "depth",
            "f4",
            "obs",
            _FillValue=math.nan,
            standard_name="depth",
            long_name="depth of the reading",
            units="m",
            positive="down",
            axis="Z",
        )[:] = [_nan(d) for d in depths]
        var(
            "depth_source",
            "i1",
            "obs",
            long_name="where depth comes from",
            flag_values=np.array([0, 1], dtype="i1"),
            flag_meanings="sonde_pressure winch_line_out",
        )[:] = [0 if s.sonde_depth_m is not None else 1 for s in kept]
        var("line_out", "f4", "obs", _FillValue=math.nan, long_name="winch line out", units="m")[
            :
        ] = [_nan(s.line_out_m) for s in kept]
        var("phase", "i1", "obs", _FillValue=BYTE_FILL, long_name="cast phase of the reading",
            flag_values=np.arange(len(PHASE_FLAGS), dtype="i1"),
            flag_meanings=" ".join(PHASE_FLAGS))[:] = [
            PHASE_FLAGS.index(s.phase) if s.phase in PHASE_FLAGS else BYTE_FILL for s in kept
        ]  # fmt: skip
        taken = {"profile", "time", "lat", "lon", "row_size", "obs_time", "depth",
                 "depth_source", "line_out", "phase"}  # fmt: skip
        for c in columns:
            name = c.name if c.name not in taken else f"sonde_{c.name}"
            attrs: dict[str, Any] = {
                "_FillValue": math.nan,
                "long_name": c.long_name,
                "units": CF_UNITS.get(c.unit, c.unit),
                "coordinates": "time lat lon depth",
            }
            if c.standard_name and name == c.name:  # `depth` is the coordinate's already
                attrs["standard_name"] = c.standard_name
            var(name, "f4", "obs", **attrs)[:] = [_nan(s.values.get(c.name)) for s in kept]
    return len(kept)
