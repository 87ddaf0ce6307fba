"""The binned profiles as CSV, and the stations table as CSV and as GeoJSON (RFC 7946).

This module owns the columns of those three files:
- `profiles.csv`: one row per cast, way (down, up) and bin holding a reading: the
  bin's centre, the mean depth of its readings, and per parameter its value at
  the centre (`P [unit]`), the readings' mean (`P_mean`), standard deviation
  (`P_sd`), count (`P_n`) and flag (`P_flag`: empty, `few` under the bins' least
  count, `empty`);
- `stations.csv` and `stations.geojson`: one row, or Point, per cast with what its
  way down says (docs/profiles.md): the thermocline (largest density gradient and
  seasonal), the metalimnion, Schmidt stability, the deep chlorophyll maximum,
  the oxycline, the top of the hypoxic water, every parameter's surface and
  bottom values; a number that cannot be read is an empty cell (null) with its
  reason in `missing` (`thermocline:mixed;schmidt_stability:no_hypsography`), never
  a zero. Names carry no unit: the CSV's header says it (`thermocline [m]`), the
  GeoJSON's `units` too.
Every CSV goes through `export.csv.writer` (formulas neutralised) and starts with
a `#` line of provenance and processing. It never reads the journal or a file.
"""

from __future__ import annotations

import json
import math
from typing import Any, TextIO

import numpy as np
import numpy.typing as npt

from cc_daemon.export.csv import comment, writer
from cc_daemon.export.profiles.survey import ProfiledCast, Survey, roles
from cc_daemon.export.provenance import of_casts
from cc_daemon.science.profiles.binning import Binned, bin_index
from cc_daemon.science.profiles.derived import QUANTITIES
from cc_daemon.store.records import iso_utc

WAYS = ("down", "up")
OXYGEN_GRADIENT_UNIT = "mg/L/m"
CAST_FIELDS = ("cast_id", "start_utc", "lat", "lon", "simulated", "bed", "reached")


def _num(value: float | None, digits: int = 4) -> str:
    return "" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def provenance_line(survey: Survey) -> str:
    s = survey.settings
    made = of_casts([c.cast for c in survey.casts])
    correction = "not corrected" if s.method == "none" else f"corrected ({s.method})"
    lags = ", ".join(f"{n} {t:g} s" for n, t in s.response_s.items() if t > 0) or "none"
    return comment(
        f"# cc-daemon profiles: winch_backend: {made.winch_backend}; simulated: "
        f"{made.simulated}; bins {s.bin_m:g} m, flagged `few` with fewer than "
        f"{s.min_count} readings; "
        f"sensor lags {correction}: {lags}"
    )


def way(cast: ProfiledCast, name: str) -> Binned:
    return cast.processed.down if name == "down" else cast.processed.up


def readings_depth(cast: ProfiledCast, name: str, bin_m: float) -> npt.NDArray[np.float64]:
    """The mean depth of the readings a way kept in each of its bins (NaN: none)."""
    profile = way(cast, name)
    depth = cast.processed.down_depth_m if name == "down" else cast.processed.up_depth_m
    if len(profile.depth_m) == 0:
        return np.array([])
    slot = bin_index(depth, bin_m) - int(bin_index(profile.depth_m[0], bin_m))
    inside = (slot >= 0) & (slot < len(profile.depth_m))
    count = np.bincount(slot[inside], minlength=len(profile.depth_m))
    total = np.bincount(slot[inside], weights=depth[inside], minlength=len(profile.depth_m))
    with np.errstate(divide="ignore", invalid="ignore"):
        found: npt.NDArray[np.float64] = np.where(count > 0, total / count, math.nan)
    return found


def flag(profile: Binned, name: str, i: int) -> str:
    if profile.count[name][i] == 0:
        return "empty"
    return "few" if profile.few[name][i] else ""


def write_profiles_csv(survey: Survey, out: TextIO) -> int:
    """One row per cast, way and bin with a reading; returns the rows written."""
    out.write(provenance_line(survey) + "\r\n")
    rows = writer(out)
    header = ["cast_id", "way", "start_utc", "lat", "lon", "depth [m]", "readings_depth [m]"]
    for c in survey.columns:
        unit = f" [{c.unit}]" if c.unit else ""
        header += [f"{c.name}{unit}", f"{c.name}_mean{unit}", f"{c.name}_sd{unit}"]
        header += [f"{c.name}_n", f"{c.name}_flag"]
    rows.writerow(header)
    written = 0
    for cast in survey.casts:
        for name in WAYS:
            profile = way(cast, name)
            where = readings_depth(cast, name, survey.settings.bin_m)
            for i, centre in enumerate(profile.depth_m):
                if not any(profile.count[c.name][i] for c in survey.columns):
                    continue
                row: list[Any] = [cast.cast.id, name, iso_utc(cast.cast.start_wall_s)]
                row += [f"{cast.cast.lat_deg:.7f}", f"{cast.cast.lon_deg:.7f}"]
                row += [f"{centre:.3f}", _num(where[i], 3)]
                for c in survey.columns:
                    row += [
                        _num(profile.value[c.name][i]),
                        _num(profile.mean[c.name][i]),
                        _num(profile.std[c.name][i]),
                        int(profile.count[c.name][i]),
                        flag(profile, c.name, i),
                    ]
                rows.writerow(row)
                written += 1
    return written


def public(name: str) -> str:
    """A quantity's name in the products: its unit said beside it, not in it."""
    return name.removesuffix("_j_m2").removesuffix("_m")


def station_units(survey: Survey) -> dict[str, str]:
    """The unit of each station field that has one."""
    unit = {c.name: c.unit for c in survey.columns}
    units = {public(name): "m" for name in QUANTITIES if name.endswith("_m")}
    units["schmidt_stability"] = "J/m2"
    units["dcm_chlorophyll"] = unit.get(roles(survey.columns).chlorophyll or "", "")
    units["oxycline_gradient"] = OXYGEN_GRADIENT_UNIT
    units.update({"bed": "m", "reached": "m", "surface_depth": "m", "bottom_depth": "m"})
    for c in survey.columns:
        units[f"surface_{c.name}"] = units[f"bottom_{c.name}"] = c.unit
    return units


def station(survey: Survey, cast: ProfiledCast) -> tuple[dict[str, Any], dict[str, str]]:
    """A station's fields in table order (None where missing) and why each is missing."""
    reading = cast.reading
    missing = {public(name): why for name, why in reading.missing.items()}
    down = cast.processed.down
    held = np.any([down.count[c.name] > 0 for c in survey.columns], axis=0)
    thin = np.any([(down.count[c.name] > 0) & down.few[c.name] for c in survey.columns], axis=0)
    fields: dict[str, Any] = {
        "cast_id": cast.cast.id,
        "start_utc": iso_utc(cast.cast.start_wall_s),
        "lat": round(cast.cast.lat_deg, 7),
        "lon": round(cast.cast.lon_deg, 7),
        "simulated": any(r.simulated for r in cast.readings),
        "bed": cast.bed_m,
        "reached": cast.cast.reached_depth_m,
        "bins": int(np.count_nonzero(held)),
        "thin_bins": int(np.count_nonzero(thin)),
    }
    if cast.bed_m is None:
        missing["bed"] = "cast_blind"
    fields.update({public(name): value for name, value in reading.numbers.items()})
    # The depths of the surface and the bottom are where the whole way down has a value.
    present = down.depth_m[held]
    fields["surface_depth"] = float(present[0]) if len(present) else None
    fields["bottom_depth"] = float(present[-1]) if len(present) else None
    for label, found in (("surface", reading.surface), ("bottom", reading.bottom)):
        for c in survey.columns:
            got = found.get(c.name)
            fields[f"{label}_{c.name}"] = None if got is None else got.value
            if got is None or got.value is None:
                missing[f"{label}_{c.name}"] = (got.missing if got else None) or "no_data"
    return fields, missing


def _header(name: str, units: dict[str, str]) -> str:
    unit = units.get(name)
    return f"{name} [{unit}]" if unit else name


def write_stations_csv(survey: Survey, out: TextIO) -> int:
    """One row per cast; returns the rows written."""
    out.write(provenance_line(survey) + "\r\n")
    rows = writer(out)
    units = station_units(survey)
    table = [station(survey, cast) for cast in survey.casts]
    names = list(table[0][0]) if table else list(CAST_FIELDS)
    rows.writerow([*(_header(n, units) for n in names), "missing"])
    for fields, missing in table:
        cells: list[Any] = []
        for name in names:
            value = fields[name]
            if isinstance(value, bool):
                cells.append(int(value))
            elif isinstance(value, float):
                cells.append(_num(value, 7 if name in ("lat", "lon") else 4))
            else:
                cells.append("" if value is None else value)
        rows.writerow([*cells, ";".join(f"{k}:{v}" for k, v in sorted(missing.items()))])
    return len(table)


def write_stations_geojson(survey: Survey, out: TextIO) -> int:
    """A FeatureCollection of one Point per cast (RFC 7946: longitude, latitude in WGS 84)."""
    units = station_units(survey)
    features = []
    for cast in survey.casts:
        fields, missing = station(survey, cast)
        properties = {
            name: (round(value, 6) if isinstance(value, float) else value)
            for name, value in fields.items()
            if name not in ("lat", "lon")
        }
        properties["missing"] = dict(sorted(missing.items()))
        properties["units"] = units
        features.append(
            {
                "type": "Feature",
                "id": f"station-{cast.cast.id}",
                "geometry": {"type": "Point", "coordinates": [fields["lon"], fields["lat"]]},
                "properties": properties,
            }
        )
    json.dump({"type": "FeatureCollection", "features": features}, out, indent=1, allow_nan=False)
    out.write("\n")
    return len(features)
