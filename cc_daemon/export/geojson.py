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
from collections.abc import Callable, Iterable, Sequence
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


# allow_nan=False: NaN is not JSON, and QGIS would reject the whole file.
_dump = json.JSONEncoder(allow_nan=False, separators=(",", ":")).encode


def _items(values: list[Any]) -> str:
    """`values` as JSON array items (no brackets): one encoder call for a batch."""
    return _dump(values)[1:-1]


def write(casts: Sequence[CastRecord], fixes: Sequence[FixRecord], out: TextIO) -> int:
    """Write the FeatureCollection to `out`; return the number of features."""
    return write_batches(casts, lambda: [fixes], out)


def write_batches(
    casts: Sequence[CastRecord],
    fix_batches: Callable[[], Iterable[Sequence[FixRecord]]],
    out: TextIO,
) -> int:
    """`write`, the same bytes, holding one batch of fixes at a time (a ten-day
    survey has 864,000): `fix_batches()` gives the fixes in order, in batches; it
    is called twice, for the track and for the soundings."""
    out.write('{"type":"FeatureCollection","features":[')
    features = 0
    if casts:
        out.write(_items([_station(c) for c in casts]))
        features += len(casts)
    track = _Track(out, comma=features > 0)
    for batch in fix_batches():
        track.add(batch)
    if track.end():
        features += 1
    for batch in fix_batches():
        if batch:
            out.write(("," if features else "") + _items([_sounding(f) for f in batch]))
            features += len(batch)
    out.write("]}\n")
    return features


class _Track:
    """The track's LineString, written as its fixes come; its properties (first
    and last time, count) close it. Nothing is written for fewer than two fixes."""

    def __init__(self, out: TextIO, *, comma: bool) -> None:
        self._out = out
        self._comma = comma
        self._first: FixRecord | None = None
        self._last: FixRecord | None = None
        self._count = 0
        self._started = False

    def _parts(self, count: int) -> tuple[str, str]:
        """`_track`'s text before and after its positions: one maker of its shape."""
        assert self._first is not None and self._last is not None
        feature = _track([self._first, self._last])
        feature["geometry"]["coordinates"] = _MARK
        feature["properties"]["fixes"] = count
        head, _, tail = _dump(feature).partition(_dump(_MARK))
        return head + "[", "]" + tail

    def add(self, batch: Sequence[FixRecord]) -> None:
        if not batch:
            return
        self._first = self._first or batch[0]
        self._last = batch[-1]
        positions = [_position(f.lon_deg, f.lat_deg) for f in batch]
        if self._started:
            self._out.write("," + _items(positions))
        elif self._count + len(batch) >= 2:  # the head, then every position so far
            if self._count:
                positions.insert(0, _position(self._first.lon_deg, self._first.lat_deg))
            head = self._parts(0)[0]
            self._out.write(("," if self._comma else "") + head + _items(positions))
            self._started = True
        self._count += len(batch)

    def end(self) -> bool:
        if self._started:
            self._out.write(self._parts(self._count)[1])
        return self._started


_MARK = "\x00positions"
