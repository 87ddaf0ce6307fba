"""NetCDF export: one vertical profile per cast, following the CF conventions.

This module owns the NetCDF layout: CF-1.8 `featureType = "profile"` in the
contiguous ragged array representation (CF 9.3.3). Each cast is a profile with
one `time`, `lat` and `lon`; its samples lie along the `obs` dimension, in
order, and `row_size` (with `sample_dimension = "obs"`) says how many belong to
each profile. Categories (the cast phase, the outcome) are small integers with
CF `flag_values` / `flag_meanings`, which xarray, Ocean Data View and Panoply
all understand, rather than strings that the classic format cannot hold.

Values are stored at their real precision: depths in metres rounded to the
millimetre, positions to 1e-7 degree (the autopilot's resolution), times to
the millisecond; `obs_time` is each sample's CF time coordinate, named by the
`coordinates` of the per-sample variables. The tests check the file with the
IOOS compliance checker's CF 1.8 suite.

The file is written in the NETCDF4_CLASSIC format, which the oldest readers
still open. netCDF4 is the optional `netcdf` extra: it is imported here, when
a file is written, never when the package is imported. This module never reads
the journal and never writes anywhere but the path it is given.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from cc_daemon import __version__
from cc_daemon.export import OptionalDependencyError
from cc_daemon.export.provenance import of_casts
from cc_daemon.store.records import CastRecord, SampleRecord
from cc_daemon.store.sonar import SonarReadingRecord

TIME_UNITS = "seconds since 1970-01-01 00:00:00 UTC"
PHASE_FLAGS = ("soaking", "descending", "dwelling", "ascending", "aborting", "stranded")
OUTCOME_FLAGS = ("completed", "skipped-shallow", "aborted", "unfinished", "running")
BYTE_FILL = -127


def _flag_meanings(names: Sequence[str]) -> str:
    # CF: flag meanings are blank-separated words; multi-word ones use underscores.
    return " ".join(name.replace("-", "_") for name in names)


def _mm(metres: float | None) -> float:
    """Metres to the millimetre (NaN for none): the finest any depth here is measured."""
    return math.nan if metres is None else round(metres, 3)


def _ms(seconds: float) -> float:
    return round(seconds, 3)


def _e7(degrees: float) -> float:
    return round(degrees, 7)


def _flag(value: str | None, names: Sequence[str]) -> int:
    return names.index(value) if value in names else BYTE_FILL


def sonar_during(
    casts: Sequence[CastRecord], read: Callable[..., list[SonarReadingRecord]]
) -> list[SonarReadingRecord]:
    """The sonar readings from the first cast's start to the last one's end."""
    if not casts:
        return []
    start = min(c.start_wall_s for c in casts)
    ends = [c.end_wall_s for c in casts]
    until = None if any(e is None for e in ends) else max(e for e in ends if e is not None)
    return read(since=start, until=until)


def write(
    casts: Sequence[CastRecord],
    samples: Sequence[SampleRecord],
    path: Path,
    *,
    sonar: Sequence[SonarReadingRecord] = (),
) -> int:
    """Write `casts` and their `samples` as CF profiles to `path`; return the sample count.

    Samples of casts not in `casts` are left out (a profile needs its station).
    Raises `ValueError` when there is no cast to write, `OptionalDependencyError`
    when netCDF4 is missing.
    """
    try:
        import netCDF4
        import numpy as np
    except ImportError as exc:
        raise OptionalDependencyError("NetCDF export", "netCDF4", "netcdf") from exc
    if not casts:
        raise ValueError("no casts to export")

    order = {cast.id: index for index, cast in enumerate(casts)}
    # The ragged array needs each profile's samples together, in profile order.
    kept = sorted(
        (s for s in samples if s.cast_id in order),
        key=lambda s: (order[s.cast_id], s.mono_s),
    )
    counts = Counter(s.cast_id for s in kept)

    with netCDF4.Dataset(str(path), "w", format="NETCDF4_CLASSIC") as nc:
        profile_globals(nc, "Probe casts of an autonomous survey boat", "export --format netcdf")
        nc.comment = (
            "Times are the companion computer's wall clock; clock_synced = 0 marks"
            " profiles recorded before the clock was synchronised. Positions are the"
            " station where the autopilot asked for the cast."
        )
        provenance = of_casts(casts)
        nc.winch_backend = provenance.winch_backend
        nc.simulated = provenance.simulated
        var = profile_file(nc, casts, counts, n_obs=len(kept), rows_are="samples")
        var(
            "clock_synced",
            "i1",
            "profile",
            long_name="wall clock synchronised at the start of the cast",
            flag_values=np.array([0, 1], dtype="i1"),
            flag_meanings="not_synchronised synchronised",
        )[:] = [int(c.start_clock_synced) for c in casts]
        var(
            "outcome",
            "i1",
            "profile",
            _FillValue=BYTE_FILL,
            long_name="how the cast ended",
            flag_values=np.arange(len(OUTCOME_FLAGS), dtype="i1"),
            flag_meanings=_flag_meanings(OUTCOME_FLAGS),
        )[:] = [_flag(c.outcome or "running", OUTCOME_FLAGS) for c in casts]
        # f8, not f4: a float32 cannot hold 0.144 m, and the millimetre is real.
        depth_attrs = {"units": "m", "positive": "down", "_FillValue": math.nan}
        var(
            "water_depth",
            "f8",
            "profile",
            long_name="distance to the bottom from the boat's sonar at the station",
            **depth_attrs,
        )[:] = [_mm(c.water_depth_m) for c in casts]
        var(
            "sonar_confidence",
            "i1",
            "profile",
            long_name="sonar confidence of water_depth",
            units="percent",
        )[:] = [c.sonar_confidence_pct for c in casts]
        var("planned_depth", "f8", "profile", long_name="planned probe depth", **depth_attrs)[:] = [
            _mm(c.planned_depth_m) for c in casts
        ]
        var("reached_depth", "f8", "profile", long_name="deepest probe depth", **depth_attrs)[:] = [
            _mm(c.reached_depth_m) for c in casts
        ]

        var(
            "obs_time",
            "f8",
            "obs",
            standard_name="time",
            long_name="time of the sample",
            units=TIME_UNITS,
            calendar="standard",
        )[:] = [_ms(s.wall_s) for s in kept]
        var(
            "depth",
            "f8",
            "obs",
            standard_name="depth",
            long_name="probe depth below the surface",
            units="m",
            positive="down",
            axis="Z",
        )[:] = [_mm(s.depth_m) for s in kept]
        var(
            "phase",
            "i1",
            "obs",
            _FillValue=BYTE_FILL,
            long_name="cast phase of the sample",
            flag_values=np.arange(len(PHASE_FLAGS), dtype="i1"),
            flag_meanings=_flag_meanings(PHASE_FLAGS),
            coordinates="obs_time lat lon depth",
        )[:] = [_flag(s.phase, PHASE_FLAGS) for s in kept]
        if sonar:
            _write_sonar(nc, sonar)
    return len(kept)


def _write_sonar(nc: Any, readings: Sequence[SonarReadingRecord]) -> None:
    """The daemon's own sonar readings over the casts' span, on their own dimension.

    Not part of the profiles (the readings are the boat's, not the probe's): a
    plain time series beside them, every reading as it arrived, with a flag for
    those that cannot be true.
    """
    import numpy as np

    nc.createDimension("sonar_obs", len(readings))

    def var(name: str, kind: str, **attrs: Any) -> Any:
        fill = attrs.pop("_FillValue", None)
        v = nc.createVariable(name, kind, ("sonar_obs",), fill_value=fill)
        v.setncatts(attrs)
        return v

    var(
        "sonar_time", "f8", standard_name="time", long_name="time of the sonar reading",
        units=TIME_UNITS, calendar="standard",
    )[:] = [_ms(r.wall_s) for r in readings]  # fmt: skip
    var(
        "sonar_distance", "f8", long_name="distance to the bottom from the companion"
        " computer's own sonar, as it arrived", units="m", positive="down",
        coordinates="sonar_time",
    )[:] = [r.distance_mm / 1000 for r in readings]  # fmt: skip
    var(
        "sonar_reading_confidence", "i2", long_name="sonar confidence, as it arrived",
        units="percent", coordinates="sonar_time",
    )[:] = [r.confidence_pct for r in readings]  # fmt: skip
    var(
        "sonar_valid", "i1", long_name="sonar reading can be true",
        flag_values=np.array([0, 1], dtype="i1"), flag_meanings="invalid valid",
        comment="invalid: confidence above 100, or a distance of 1 km or more",
        coordinates="sonar_time",
    )[:] = [int(r.valid) for r in readings]  # fmt: skip


def profile_globals(nc: Any, title: str, command: str) -> None:
    """The global attributes every CF profile file here starts with: the conventions,
    the feature type, `title`, the source, and its creation by `cc-daemon <command>`."""
    nc.Conventions = "CF-1.8"
    nc.featureType = "profile"
    nc.cdm_data_type = "Profile"
    nc.title = title
    nc.source = f"cc-daemon {__version__} survey journal"
    created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    nc.date_created = created
    nc.history = f"{created} written by cc-daemon {__version__} {command}"


def profile_file(
    nc: Any, casts: Sequence[CastRecord], counts: Mapping[Any, int], *, n_obs: int, rows_are: str
) -> Any:
    """The CF profile layout every NetCDF export here shares (contiguous ragged
    array): the dimensions, and per profile its id, start time, position and row
    count. Returns the variable maker, `var(name, kind, dim, **attributes)`."""
    nc.createDimension("profile", len(casts))
    nc.createDimension("obs", n_obs)

    def var(name: str, kind: str, dim: str, **attrs: Any) -> Any:
        fill = attrs.pop("_FillValue", None)
        variable = nc.createVariable(name, kind, (dim,), fill_value=fill)
        variable.setncatts(attrs)
        return variable

    var("profile", "i4", "profile", cf_role="profile_id", long_name="cast id")[:] = [
        c.id for c in casts
    ]
    var(
        "time",
        "f8",
        "profile",
        standard_name="time",
        long_name="start of the cast",
        units=TIME_UNITS,
        calendar="standard",
        axis="T",
    )[:] = [_ms(c.start_wall_s) for c in casts]
    var(
        "lat",
        "f8",
        "profile",
        standard_name="latitude",
        long_name="station latitude",
        units="degrees_north",
        axis="Y",
    )[:] = [_e7(c.lat_deg) for c in casts]
    var(
        "lon",
        "f8",
        "profile",
        standard_name="longitude",
        long_name="station longitude",
        units="degrees_east",
        axis="X",
    )[:] = [_e7(c.lon_deg) for c in casts]
    var(
        "row_size",
        "i4",
        "profile",
        long_name=f"number of {rows_are} in this profile",
        sample_dimension="obs",
    )[:] = [counts.get(c.id, 0) for c in casts]
    return var
