"""The sonde's readings out of the journal: the map, sample CSV and station GeoJSON.

This module owns
- `parameter_map`: the register map the readings were taken with, from the
  journal's last `sonde_started` event (so units and names come with the
  data), else the default map, plus any name found in the readings;
- the sample CSV: one row per reading, one column per parameter with its unit
  in the header (`temperature [degC]`), a missing value an empty cell (its
  reason in `missing`), never a zero; its cells neutralised against formulas
  as every CSV's (`export.csv.writer`);
- the station GeoJSON: one Point per cast with the values near the surface
  and at the bottom of its profile.
It never reads the journal itself (the caller hands it records).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, TextIO

from cc_daemon.config.sonde import DEFAULT_PARAMETERS
from cc_daemon.export.csv import writer as csv_writer
from cc_daemon.store.records import CastRecord, EventRecord, iso_utc
from cc_daemon.store.sonde import SondeSampleRecord

# A reading this shallow or shallower (sonde depth, metres) counts as "surface".
SURFACE_MAX_M = 1.0


@dataclass(frozen=True, slots=True)
class Column:
    name: str
    unit: str
    long_name: str
    standard_name: str | None


def parameter_map(
    events: Iterable[EventRecord], samples: Sequence[SondeSampleRecord] = ()
) -> list[Column]:
    """The parameters in map order, with the units they were recorded in."""
    columns: list[Column] = []
    for event in events:
        if event.kind == "sonde_started" and isinstance(event.detail.get("parameters"), list):
            columns = [
                Column(
                    str(p.get("name")),
                    str(p.get("unit", "")),
                    str(p.get("long_name", p.get("name"))),
                    p.get("standard_name"),
                )
                for p in event.detail["parameters"]
                if isinstance(p, dict)
            ]
    if not columns:
        columns = [Column(p.name, p.unit, p.long_name, p.standard_name) for p in DEFAULT_PARAMETERS]
    known = {c.name for c in columns}
    for s in samples:
        for name in s.values:
            if name not in known:
                known.add(name)
                columns.append(Column(name, "", name, None))
    return columns


def header(column: Column) -> str:
    return f"{column.name} [{column.unit}]" if column.unit else column.name


def _num(value: float | None, digits: int = 4) -> str:
    return "" if value is None else f"{value:.{digits}f}"


FIXED_COLUMNS = (
    "cast_id",
    "time_utc",
    "phase",
    "lat",
    "lon",
    "line_out [m]",
    "sonde_depth [m]",
    "status",
)
TRAILING_COLUMNS = ("missing", "simulated", "clock_synced", "monotonic_s")


def write_csv(
    samples: Iterable[SondeSampleRecord],
    columns: Sequence[Column],
    casts: Sequence[CastRecord],
    out: TextIO,
) -> int:
    """One row per reading; returns the number of rows written."""
    where = {c.id: (c.lat_deg, c.lon_deg) for c in casts}
    writer = csv_writer(out)
    writer.writerow((*FIXED_COLUMNS, *(header(c) for c in columns), *TRAILING_COLUMNS))
    count = 0
    for s in samples:
        lat, lon = where.get(s.cast_id, (None, None)) if s.cast_id is not None else (None, None)
        writer.writerow(
            (
                "" if s.cast_id is None else s.cast_id,
                iso_utc(s.wall_s),
                s.phase,
                "" if lat is None else f"{lat:.7f}",
                "" if lon is None else f"{lon:.7f}",
                _num(s.line_out_m, 3),
                _num(s.sonde_depth_m, 3),
                s.status,
                *(_num(s.values.get(c.name)) for c in columns),
                ";".join(f"{k}:{v}" for k, v in sorted(s.missing.items())),
                int(s.simulated),
                int(s.clock_synced),
                f"{s.mono_s:.3f}",
            )
        )
        count += 1
    return count


def surface_and_bottom(
    samples: Sequence[SondeSampleRecord],
) -> tuple[SondeSampleRecord | None, SondeSampleRecord | None]:
    """A profile's surface reading (the shallowest at most 1 m down) and its deepest."""
    valid = [s for s in samples if s.sonde_depth_m is not None and s.status in ("ok", "partial")]
    if not valid:
        return None, None
    shallow = [s for s in valid if (s.sonde_depth_m or 0.0) <= SURFACE_MAX_M]
    surface = min(shallow, key=lambda s: s.sonde_depth_m or 0.0) if shallow else None
    bottom = max(valid, key=lambda s: s.sonde_depth_m or 0.0)
    return surface, bottom


def write_geojson(
    casts: Sequence[CastRecord],
    samples: Sequence[SondeSampleRecord],
    columns: Sequence[Column],
    out: TextIO,
) -> int:
    """A FeatureCollection of station Points with surface and bottom values."""
    features: list[dict[str, Any]] = []
    for cast in casts:
        surface, bottom = surface_and_bottom([s for s in samples if s.cast_id == cast.id])
        props: dict[str, Any] = {
            "feature": "sonde_station",
            "cast_id": cast.id,
            "start_utc": iso_utc(cast.start_wall_s),
            "outcome": cast.outcome or "running",
            "simulated": any(s.simulated for s in samples if s.cast_id == cast.id),
        }
        for label, reading in (("surface", surface), ("bottom", bottom)):
            depth = None if reading is None else reading.sonde_depth_m
            props[f"{label}_depth_m"] = None if depth is None else round(depth, 3)
            for c in columns:
                value = None if reading is None else reading.values.get(c.name)
                props[f"{label}_{c.name}"] = None if value is None else round(value, 4)
        props["units"] = {c.name: c.unit for c in columns}
        features.append(
            {
                "type": "Feature",
                "id": f"sonde-{cast.id}",
                "geometry": {
                    "type": "Point",
                    "coordinates": [round(cast.lon_deg, 7), round(cast.lat_deg, 7)],
                },
                "properties": props,
            }
        )
    json.dump({"type": "FeatureCollection", "features": features}, out, indent=1)
    out.write("\n")
    return len(features)
