"""GeoJSON export of a survey: stations, the boat's track and the sonar soundings.

This module owns the shape of the GeoJSON document: one RFC 7946
FeatureCollection holding
- a Point per cast station (`"feature": "station"`) with the cast's
  properties (times, outcome, planned and reached depth, water depth),
- the track as one LineString (`"feature": "track"`) through every fix,
- a Point per fix (`"feature": "sounding"`) with the sonar's `depth_m` and
  `confidence_pct`.
QGIS opens it as three layers (points, line, points), split by the
`feature` property or geometry type. Positions are `[lon, lat]` in WGS 84
degrees (RFC 7946 has no other CRS and no `crs` member), rounded to 1e-7 degree,
the autopilot's resolution; depths in metres rounded to the millimetre (the
resolution of the wire and the winch: never `0.14400000000000002`); times
ISO 8601 UTC to the millisecond.

It never reads the journal itself and never invents positions: a record
without one is left out.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any, TextIO

from cc_daemon.store.records import CastRecord, FixRecord, iso_utc


def _position(lon: float, lat: float) -> list[float]:
    return [round(lon, 7), round(lat, 7)]


def _mm(metres: float | None) -> float | None:
    """Metres to the millimetre, the finest any depth here is measured."""
    return None if metres is None else round(metres, 3)


def _station(cast: CastRecord) -> dict[str, Any]:
    return {
        "type": "Feature",
        "id": f"cast-{cast.id}",
        "geometry": {"type": "Point", "coordinates": _position(cast.lon_deg, cast.lat_deg)},
        "properties": {
            "feature": "station",
            "cast_id": cast.id,
            "start_utc": iso_utc(cast.start_wall_s),
            "end_utc": iso_utc(cast.end_wall_s) or None,
            "clock_synced": cast.start_clock_synced,
            "outcome": cast.outcome or "running",
            "reason": cast.reason,
            "mode": cast.mode,
            "planned_depth_m": _mm(cast.planned_depth_m),
            "reached_depth_m": _mm(cast.reached_depth_m),
            "water_depth_m": _mm(cast.water_depth_m),
            "sonar_confidence_pct": cast.sonar_confidence_pct,
            "samples": cast.samples,
            "winch_backend": cast.winch_backend,
            "simulated": cast.simulated,
        },
    }


def _track(fixes: Sequence[FixRecord]) -> dict[str, Any]:
    return {
        "type": "Feature",
        "id": "track",
        "geometry": {
            "type": "LineString",
            "coordinates": [_position(f.lon_deg, f.lat_deg) for f in fixes],
        },
        "properties": {
            "feature": "track",
            "start_utc": iso_utc(fixes[0].wall_s),
            "end_utc": iso_utc(fixes[-1].wall_s),
            "fixes": len(fixes),
        },
    }


def _sounding(fix: FixRecord) -> dict[str, Any]:
    return {
        "type": "Feature",
        "geometry": {"type": "Point", "coordinates": _position(fix.lon_deg, fix.lat_deg)},
        "properties": {
            "feature": "sounding",
            "time_utc": iso_utc(fix.wall_s),
            "clock_synced": fix.clock_synced,
            "depth_m": _mm(fix.sonar_distance_m),
            "confidence_pct": fix.sonar_confidence_pct,
        },
    }


def feature_collection(casts: Sequence[CastRecord], fixes: Sequence[FixRecord]) -> dict[str, Any]:
    """The survey as a GeoJSON FeatureCollection (a dict ready for `json.dump`)."""
    features = [_station(c) for c in casts]
    # RFC 7946 3.1.4: a LineString needs two or more positions.
    if len(fixes) >= 2:
        features.append(_track(fixes))
    features.extend(_sounding(f) for f in fixes)
    return {"type": "FeatureCollection", "features": features}


def write(casts: Sequence[CastRecord], fixes: Sequence[FixRecord], out: TextIO) -> int:
    """Write the FeatureCollection to `out`; return the number of features."""
    collection = feature_collection(casts, fixes)
    # allow_nan=False: NaN is not JSON, and QGIS would reject the whole file.
    json.dump(collection, out, allow_nan=False, separators=(",", ":"))
    out.write("\n")
    return len(collection["features"])
