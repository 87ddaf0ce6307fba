"""The journal as the page's JSON: surveys, a survey's map (stations, track, casts), a
cast's profile, events, the latest readings. Blocking reads through `JournalReader`
(read-only), run off the event loop by the server; it never writes to the journal.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from cc_daemon.export import estimates
from cc_daemon.export.mapframe import EARTH_RADIUS_M, LocalFrame
from cc_daemon.store import JournalReader, StoreError
from cc_daemon.store.records import EventRecord
from cc_daemon.store.stationrows import first_events
from cc_daemon.store.stations import names
from cc_daemon.store.surveys import SurveyRecord
from cc_daemon.store.track import Extent, track
from cc_daemon.store.values import json_value


class NotFound(StoreError):
    """No such survey or cast: a 404, not a broken journal."""


def _clean(value: Any) -> Any:
    """JSON has no NaN or infinity: they become null (a value that cannot be shown)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


def _open(path: Path) -> JournalReader:
    if not path.exists():
        raise StoreError(f"no journal at {path} yet (the daemon has recorded nothing)")
    return JournalReader(path)


def _choose(reader: JournalReader, survey: int) -> SurveyRecord | None:
    try:
        return reader.select_survey(survey)
    except StoreError as exc:
        raise NotFound(str(exc)) from None


def undamaged_survey(reader: JournalReader, survey: int) -> SurveyRecord | None:
    """Narrow `reader` to `survey` (NotFound if there is none) and refuse a damaged
    journal (StoreError, its damage in one line) before anything is made from it."""
    chosen = _choose(reader, survey)
    damage = reader.damage_report()
    if damage is not None:
        raise StoreError(damage)
    return chosen


def surveys(path: Path) -> dict[str, Any]:
    with _open(path) as reader:
        return {"surveys": [_clean(s._asdict()) for s in reader.surveys()]}


def survey_casts(path: Path, survey: int) -> dict[str, Any]:
    """The survey's map and casts: its stations (`store.stations`: their names, the
    planned ones never asked included), its track (thinned to a few thousand fixes),
    and each cast with its station's name, all in metres east and north of the
    south-west corner of the track and the stations: the frame, and so the origin,
    `cc-daemon plot --survey` draws the survey in."""
    with _open(path) as reader:
        _choose(reader, survey)
        casts = reader.casts()
        stations = reader.stations()
        sailed = track(reader, survey)
    out: dict[str, Any] = {"survey": survey, "origin": None, "casts": [], "stations": [],
                           "track": []}  # fmt: skip
    lats = [c.lat_deg for c in casts] + [s.lat_deg for s in stations if not s.cast_ids]
    lons = [c.lon_deg for c in casts] + [s.lon_deg for s in stations if not s.cast_ids]
    frame = _frame(sailed.extent, lats, lons)
    if frame is None:
        return out
    out["origin"] = frame.origin_text()
    # The frame itself, to draw longitudes and latitudes (the science's) in it.
    out["frame"] = {"lat0": frame.lat0, "lon0": frame.lon0, "cos_lat": frame.cos_lat,
                    "radius_m": EARTH_RADIUS_M}  # fmt: skip
    named = names(stations)
    for cast in casts:
        row = cast._asdict()
        row["station"] = named.get(cast.id)
        row["east_m"], row["north_m"] = _metres(frame, cast.lat_deg, cast.lon_deg)
        out["casts"].append(_clean(row))
    for station in stations:
        east, north = _metres(frame, station.lat_deg, station.lon_deg)
        out["stations"].append({**station._asdict(), "east_m": east, "north_m": north})
    out["track"] = [_metres(frame, lat, lon) for lat, lon in sailed.points]
    return _clean(out)  # type: ignore[no-any-return]


def _frame(extent: Extent | None, lats: list[float], lons: list[float]) -> LocalFrame | None:
    """`LocalFrame.around` every fix and these positions, from the fixes' extent."""
    count = len(lats) + (extent.fixes if extent else 0)
    if not count:
        return None
    lat0 = min([*lats, *([extent.min_lat] if extent else [])])
    lon0 = min([*lons, *([extent.min_lon] if extent else [])])
    mean = (sum(lats) + (extent.lat_sum if extent else 0.0)) / count
    return LocalFrame(lat0, lon0, max(math.cos(math.radians(mean)), 1e-6))


def _metres(frame: LocalFrame, lat: float, lon: float) -> tuple[float, float]:
    return round(frame.east_m(lon), 2), round(frame.north_m(lat), 2)


def cast_profile(path: Path, cast_id: int) -> dict[str, Any]:
    """One cast: the winch's depths against time (samples, each estimate with its range,
    and the winch's depth at a fault between two samples), the sonde's readings taken
    in it (the way down and the way up told apart by their phase), the units of the
    sonde's parameters, and the cast's station."""
    with _open(path) as reader:
        found = reader.casts(cast_id=cast_id)
        if not found:
            raise NotFound(f"no cast {cast_id} in the journal")
        cast = found[0]
        samples = reader.samples(cast_id=cast_id)
        sonde = reader.sonde_samples(cast_id=cast_id)
        if cast.session_id is not None:
            reader.select_survey(cast.session_id)
        happened = reader.events(since=cast.start_wall_s - 1.0)
        named = names(reader.stations())
        began = _began(reader, cast.session_id)
    estimate = estimates.of_casts([cast], happened).get(cast.id)
    trace = estimates.trace(cast, samples, happened, estimate)
    profile: dict[str, Any] = _clean(
        {
            "cast": {**cast._asdict(), "station": named.get(cast.id)},
            "samples": [
                {
                    "t_s": round(cast.start_wall_s + p.mono_s - cast.start_mono_s, 3),
                    "depth_m": p.depth_m,
                    "phase": p.phase,
                    "low_m": p.low_m,
                    "high_m": p.high_m,
                    "sampled": p.sampled,
                }
                for p in trace
            ],
            "sonde": [
                {
                    "t_s": round(s.wall_s, 3),
                    "phase": s.phase,
                    "status": s.status,
                    "depth_m": s.sonde_depth_m if s.sonde_depth_m is not None else s.line_out_m,
                    "values": s.values,
                }
                for s in sonde
            ],
            "parameters": _parameters(began, sonde),
        }
    )
    return profile


def _parameters(happened: list[EventRecord], samples: list[Any]) -> list[dict[str, str]]:
    """The sonde's parameters as its map names them, with their units."""
    from cc_daemon.export.sonde import parameter_map

    return [
        {"name": c.name, "unit": c.unit, "long_name": c.long_name}
        for c in parameter_map(happened, samples)
    ]


def events(path: Path, survey: int | None) -> dict[str, Any]:
    """The events of one survey (the latest one if None)."""
    with _open(path) as reader:
        if survey is None:
            chosen = reader.select_survey("latest")
            survey = None if chosen is None else chosen.id
        else:
            _choose(reader, survey)
        rows = reader.events()
    return {"survey": survey, "events": [_clean(e._asdict()) for e in rows]}


LATEST_WINDOW_S = 600.0  # the sonde's last reading is looked for in the survey's last 10 min
BEGINNING_EVENTS = 64  # the sonde's register map is among a session's first events


def latest(path: Path, now_wall_s: float) -> dict[str, Any]:
    """The sonde's and the daemon's own sonar's last readings in the latest survey,
    each with its age (None: none in its last LATEST_WINDOW_S), and the units of the
    sonde's parameters (from the register map its session began with)."""
    with _open(path) as reader:
        survey = reader.select_survey("latest")
        if survey is None:
            return {"survey": None, "sonde": None, "sonar": None, "parameters": []}
        since = survey.end_wall_s - LATEST_WINDOW_S
        found = reader.sonde_samples(since=since)
        pings = reader.sonar_readings(since=since)
        began = _began(reader, survey.id)
    sonar = None
    if pings:
        ping = pings[-1]
        sonar = {
            "wall_s": ping.wall_s,
            "age_s": round(now_wall_s - ping.wall_s, 1),
            "port": ping.port,
            "distance_m": ping.distance_mm / 1000.0,
            "confidence_pct": ping.confidence_pct,
            "valid": ping.valid,  # stored as it came; an impossible one is flagged
        }
    out: dict[str, Any] = {"survey": survey.id, "sonde": None, "sonar": sonar,
                           "parameters": _parameters(began, found)}  # fmt: skip
    if not found:
        return out
    last = found[-1]
    reading = {
        "wall_s": last.wall_s,
        "age_s": round(now_wall_s - last.wall_s, 1),
        "status": last.status,
        "error": last.error,
        "depth_m": last.sonde_depth_m,
        "line_out_m": last.line_out_m,
        "cast_id": last.cast_id,
        "simulated": last.simulated,
        "values": last.values,
    }
    return {**out, "sonde": _clean(reading)}


def aged(doc: dict[str, Any], now_wall_s: float) -> dict[str, Any]:
    """`latest`'s answer with each reading's age as of `now_wall_s` (the answer is shared
    among the page's clients for a few seconds; an age must not be)."""
    out = dict(doc)
    for key in ("sonde", "sonar"):
        if out.get(key):
            out[key] = {**out[key], "age_s": round(now_wall_s - out[key]["wall_s"], 1)}
    return out


def _began(reader: JournalReader, session: int | None) -> list[EventRecord]:
    """The session's `sonde_started` event (the sonde's register map), if among its first."""
    if session is None:
        return []
    return [
        EventRecord(session, 0.0, 0.0, True, kind, _json(detail))
        for kind, detail in first_events(reader, session, BEGINNING_EVENTS)
        if kind == "sonde_started"
    ]


def _json(detail: Any) -> dict[str, Any]:
    try:
        value = json_value(detail)
    except ValueError:
        return {}
    return value if isinstance(value, dict) else {}
