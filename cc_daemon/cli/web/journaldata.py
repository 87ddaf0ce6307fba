"""The journal as the page's JSON: surveys, a survey's casts on a metric map, a cast's
profile, events. Blocking reads through `JournalReader` (read-only), run off the
event loop by the server; it never writes to the journal.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from cc_daemon.export.mapframe import LocalFrame
from cc_daemon.store import JournalReader, StoreError


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


def _choose(reader: JournalReader, survey: int) -> None:
    try:
        reader.select_survey(survey)
    except StoreError as exc:
        raise NotFound(str(exc)) from None


def surveys(path: Path) -> dict[str, Any]:
    with _open(path) as reader:
        return {"surveys": [_clean(s._asdict()) for s in reader.surveys()]}


def survey_casts(path: Path, survey: int) -> dict[str, Any]:
    """The survey's casts, each with its station in metres east and north of the
    survey's south-west corner (the frame the survey plot draws in)."""
    with _open(path) as reader:
        _choose(reader, survey)
        casts = reader.casts()
    out: dict[str, Any] = {"survey": survey, "origin": None, "casts": []}
    if not casts:
        return out
    frame = LocalFrame.around([c.lat_deg for c in casts], [c.lon_deg for c in casts])
    out["origin"] = frame.origin_text()
    for cast in casts:
        row = cast._asdict()
        row["east_m"] = round(frame.east_m(cast.lon_deg), 2)
        row["north_m"] = round(frame.north_m(cast.lat_deg), 2)
        out["casts"].append(_clean(row))
    return out


def cast_profile(path: Path, cast_id: int) -> dict[str, Any]:
    """The winch's depth samples of one cast and the sonde's readings taken in it."""
    with _open(path) as reader:
        found = reader.casts(cast_id=cast_id)
        if not found:
            raise NotFound(f"no cast {cast_id} in {path}")
        samples = reader.samples(cast_id=cast_id)
        sonde = reader.sonde_samples(cast_id=cast_id)
    profile: dict[str, Any] = _clean(
        {
            "cast": found[0]._asdict(),
            "samples": [
                {"t_s": round(s.wall_s, 3), "depth_m": s.depth_m, "phase": s.phase} for s in samples
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
        }
    )
    return profile


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


def latest(path: Path, now_wall_s: float) -> dict[str, Any]:
    """The sonde's and the daemon's own sonar's last readings in the latest survey,
    each with its age (None: none in its last LATEST_WINDOW_S)."""
    with _open(path) as reader:
        survey = reader.select_survey("latest")
        if survey is None:
            return {"survey": None, "sonde": None, "sonar": None}
        since = survey.end_wall_s - LATEST_WINDOW_S
        found = reader.sonde_samples(since=since)
        pings = reader.sonar_readings(since=since)
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
    if not found:
        return {"survey": survey.id, "sonde": None, "sonar": sonar}
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
    return {"survey": survey.id, "sonde": _clean(reading), "sonar": sonar}
