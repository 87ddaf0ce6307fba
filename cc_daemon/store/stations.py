"""Stations: the places a survey measures, named as the operator knows them (S1, S2...).

The autopilot's frames carry no station number: a station is a place where the
autopilot asked for a cast. A survey's stations are named in the order it
first asked at each, S1 the first; a later cast within `MATCH_RADIUS_M` of a
station is at that station (the same station asked again after its re-arm
window).

Where the survey's plan is in the journal (an event `stations_planned`, which
`cc-daemon --simulate` records with its mission, among its session's first
`PLAN_WITHIN` events: the names its summary prints),
the plan's names are used, a cast being at the planned station within
`MATCH_RADIUS_M`, and a planned station where no cast was asked (its
start-measuring frame lost, or never reached) is a station all the same: the
survey's count of stations is the plan's. Whether a station could be cast at
is the plan's word where it has one; else a station is castable unless its
casts were all skipped as too shallow.

This is the one naming and the one count of stations for every command, export
and the field page. Pure: records in, stations out; it never reads the journal.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, NamedTuple, TypeGuard

PLAN_EVENT = "stations_planned"
# The plan is looked for among a simulated session's first events only (the reader
# finds them without reading the events table whole): the simulator records it as
# soon as the daemon is ready, after a handful of the daemon's own.
PLAN_WITHIN = 64
# A cast belongs to the station within this: the daemon's own `cast.rearm_distance_m`
# default, within which a station asked again is the same station.
MATCH_RADIUS_M = 10.0
_EARTH_RADIUS_M = 6_371_000.0
_MAX_PLANNED = 10_000  # more than any survey plans: a detail past it is not a plan


class Place(NamedTuple):
    """What naming needs of a cast: its id, where it was asked, how it ended."""

    id: int
    lat_deg: float
    lon_deg: float
    outcome: str | None


class PlannedStation(NamedTuple):
    name: str
    lat_deg: float
    lon_deg: float
    castable: bool | None  # None: the plan does not say


class Station(NamedTuple):
    name: str  # "S1": the plan's name, else the order it was first asked in
    lat_deg: float
    lon_deg: float
    cast_ids: tuple[int, ...]  # its casts, first to last; () if none was asked
    castable: bool
    measured: bool  # a cast there completed
    planned: bool  # it is in the survey's plan


class Counts(NamedTuple):
    stations: int
    castable: int
    measured: int


def plan_detail(stations: Iterable[tuple[str, float, float, bool | None]]) -> dict[str, Any]:
    """The `stations_planned` event's detail for a plan of (name, lat, lon, castable)."""
    return {
        "stations": [
            {"name": name, "lat_deg": round(lat, 7), "lon_deg": round(lon, 7), "castable": ok}
            for name, lat, lon, ok in stations
        ]
    }


def read_plan(detail: Mapping[str, Any] | None) -> list[PlannedStation] | None:
    """The plan a `stations_planned` event's detail holds; None if it holds none that
    can be true (a detail from a damaged or foreign journal is ignored, not trusted)."""
    listed = detail.get("stations") if isinstance(detail, Mapping) else None
    if not isinstance(listed, list) or not 0 < len(listed) <= _MAX_PLANNED:
        return None
    plan: list[PlannedStation] = []
    for item in listed:
        if not isinstance(item, Mapping):
            return None
        name, lat, lon = item.get("name"), item.get("lat_deg"), item.get("lon_deg")
        castable = item.get("castable")
        if not (isinstance(name, str) and 0 < len(name) <= 40 and name.isprintable()):
            return None
        if not (_finite(lat) and _finite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180):
            return None
        ok = castable if isinstance(castable, bool) else None
        plan.append(PlannedStation(name, float(lat), float(lon), ok))
    return plan


def _finite(value: Any) -> TypeGuard[float]:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Metres between two positions (equirectangular: exact enough within a lake)."""
    north = math.radians(lat2 - lat1) * _EARTH_RADIUS_M
    east = math.radians(lon2 - lon1) * _EARTH_RADIUS_M * math.cos(math.radians((lat1 + lat2) / 2))
    return math.hypot(east, north)


def stations(casts: Sequence[Place], plan: Sequence[PlannedStation] | None) -> list[Station]:
    """The survey's stations in order (the plan's, then any asked elsewhere), each
    with its casts. `casts` are one survey's, in the order they were asked."""
    found: list[dict[str, Any]] = [
        {"name": p.name, "lat": p.lat_deg, "lon": p.lon_deg, "casts": [], "castable": p.castable,
         "planned": True}
        for p in plan or ()
    ]  # fmt: skip
    for cast in casts:
        nearest = min(
            found,
            key=lambda s: distance_m(s["lat"], s["lon"], cast.lat_deg, cast.lon_deg),
            default=None,
        )
        near = nearest is not None and (
            distance_m(nearest["lat"], nearest["lon"], cast.lat_deg, cast.lon_deg) <= MATCH_RADIUS_M
        )
        if nearest is not None and near:
            nearest["casts"].append(cast)
            continue
        found.append(
            {"name": f"S{len(found) + 1}", "lat": cast.lat_deg, "lon": cast.lon_deg,
             "casts": [cast], "castable": None, "planned": False}
        )  # fmt: skip
    out: list[Station] = []
    for s in found:
        outcomes = [c.outcome for c in s["casts"]]
        castable = s["castable"]
        if castable is None:  # asked, and not only ever too shallow
            castable = not outcomes or any(o != "skipped-shallow" for o in outcomes)
        out.append(
            Station(
                name=s["name"],
                lat_deg=s["lat"],
                lon_deg=s["lon"],
                cast_ids=tuple(c.id for c in s["casts"]),
                castable=castable,
                measured="completed" in outcomes,
                planned=s["planned"],
            )
        )
    return out


def names(stations_: Iterable[Station]) -> dict[int, str]:
    """Each cast's station name, by cast id."""
    return {cast_id: s.name for s in stations_ for cast_id in s.cast_ids}


def counts(stations_: Sequence[Station]) -> Counts:
    return Counts(
        stations=len(stations_),
        castable=sum(s.castable for s in stations_),
        measured=sum(s.measured for s in stations_),
    )
