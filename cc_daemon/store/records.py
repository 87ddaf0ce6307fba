"""The journal's rows as records in SI units: casts, samples, fixes and events.

This module owns the record types the read side hands out (degrees, metres,
seconds), the columns each is read from, and the conversion of one stored row
into one record. A row whose values cannot be true (text where a time belongs,
a time no calendar has, a position off the globe) raises `ValueError` or
`TypeError`, and the reader skips and counts it; a plan or an event's detail
that is not JSON, or JSON too deep or too big to be the journal's own, is kept
as `{"unreadable_plan"|"unreadable_detail": ...}` and counted.

Pure: rows in, records out; it never opens a file (`store.reader` does).
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any, NamedTuple

from cc_daemon.store.values import (
    integer,
    json_value,
    number,
    optional_number,
    optional_wall_time,
    text,
    wall_time,
)

UNREADABLE_JSON = frozenset({"unreadable_detail", "unreadable_plan"})
_SHOWN = 200  # characters of an unreadable value kept to show what it was


class CastRecord(NamedTuple):
    id: int
    session_id: int | None
    start_mono_s: float
    start_wall_s: float
    start_clock_synced: bool
    ap_timestamp_s: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    water_depth_m: float  # the sonar distance in the cast's `M` frame
    sonar_confidence_pct: int
    planned_depth_m: float
    mode: str
    plan: dict[str, Any]
    end_mono_s: float | None
    end_wall_s: float | None
    outcome: str | None  # None while the cast runs (or until the daemon reopens the file)
    reached_depth_m: float | None
    reason: str | None
    samples: int
    winch_backend: str | None = None  # "sim", "gpio", "gpio-mock"; None: not recorded
    simulated: bool | None = None  # True: no probe moved (a simulated winch)


class SampleRecord(NamedTuple):
    cast_id: int
    mono_s: float
    wall_s: float
    clock_synced: bool
    depth_m: float
    phase: str
    lat_deg: float | None  # the station's position: the boat holds it during the cast
    lon_deg: float | None


class FixRecord(NamedTuple):
    session_id: int | None
    mono_s: float
    wall_s: float
    clock_synced: bool
    frame: str
    ap_timestamp_s: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    sonar_distance_m: float
    sonar_confidence_pct: int
    # The autopilot's clock, decoded in the byte order its session settled on (the
    # first frames re-decoded once the order was learnt); None before journal v6.
    ap_time_s: int | None = None
    ap_time_order: str | None = None


class EventRecord(NamedTuple):
    session_id: int | None
    mono_s: float
    wall_s: float
    clock_synced: bool
    kind: str
    detail: dict[str, Any]


def iso_utc(wall_s: float | None) -> str:
    """Unix seconds as ISO 8601 UTC with milliseconds and a `Z`; '' for None."""
    if wall_s is None:
        return ""
    stamp = datetime.fromtimestamp(wall_s, tz=UTC).isoformat(timespec="milliseconds")
    return stamp.replace("+00:00", "Z")


def parse_time(text: str) -> float:
    """ISO 8601 (`2024-05-01`, `2024-05-01T10:00Z`, with an offset) as Unix seconds.

    A time without an offset is taken as UTC, like every time in the journal.
    """
    stamp = datetime.fromisoformat(text.strip())
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=UTC)
    return stamp.timestamp()


CAST_COLUMNS = (
    "id, session_id, start_mono_s, start_wall_s, start_clock_synced, ap_timestamp_s,"
    " lat_e7, lon_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct, planned_depth_m, mode,"
    " plan_json, end_mono_s, end_wall_s, outcome, reached_depth_m, reason,"
    " (SELECT count(*) FROM samples WHERE cast_id = casts.id), winch_backend, simulated"
)
FIX_COLUMNS = (
    "session_id, mono_s, wall_s, clock_synced, frame, ap_timestamp_s, lat_e7, lon_e7, alt_mm,"
    " sonar_distance_mm, sonar_confidence_pct, ap_time_s, ap_time_order"
)
EVENT_COLUMNS = "session_id, mono_s, wall_s, clock_synced, kind, detail_json"


def optional_id(value: Any, what: str) -> int | None:
    return None if value is None else integer(value, what)


def optional_text(value: Any, what: str) -> str | None:
    return None if value is None else text(value, what)


def degrees(lat_e7: Any, lon_e7: Any) -> tuple[float, float]:
    """A position stored as degrees x 1e7, on the globe."""
    lat = number(lat_e7, "latitude") / 1e7
    lon = number(lon_e7, "longitude") / 1e7
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise ValueError(f"position {lat:g}, {lon:g} is off the globe")
    return lat, lon


def _json_object(raw: Any, unreadable: str, name: str) -> dict[str, Any]:
    try:
        value = json_value(raw)
    except ValueError:
        return {unreadable: repr(raw)[:_SHOWN]}
    return value if isinstance(value, dict) else {name: value}


def cast(row: tuple[Any, ...]) -> CastRecord:
    lat, lon = degrees(row[6], row[7])
    return CastRecord(
        id=integer(row[0], "a cast's id"),
        session_id=optional_id(row[1], "a session"),
        start_mono_s=number(row[2], "start_mono_s"),
        start_wall_s=wall_time(row[3], "start_wall_s"),
        start_clock_synced=bool(row[4]),
        ap_timestamp_s=integer(row[5], "ap_timestamp_s"),
        lat_deg=lat,
        lon_deg=lon,
        alt_m=number(row[8], "alt_mm") / 1000.0,
        water_depth_m=number(row[9], "sonar_distance_mm") / 1000.0,
        sonar_confidence_pct=integer(row[10], "sonar_confidence_pct"),
        planned_depth_m=number(row[11], "planned_depth_m"),
        mode=text(row[12], "mode"),
        plan=_json_object(row[13], "unreadable_plan", "plan"),
        end_mono_s=optional_number(row[14], "end_mono_s"),
        end_wall_s=optional_wall_time(row[15], "end_wall_s"),
        outcome=optional_text(row[16], "outcome"),
        reached_depth_m=optional_number(row[17], "reached_depth_m"),
        reason=optional_text(row[18], "reason"),
        samples=row[19],
        winch_backend=optional_text(row[20], "winch_backend"),
        simulated=None if row[21] is None else bool(row[21]),
    )


def event(r: tuple[Any, ...]) -> EventRecord:
    return EventRecord(
        optional_id(r[0], "a session"),
        number(r[1], "mono_s"),
        wall_time(r[2], "wall_s"),
        bool(r[3]),
        text(r[4], "an event's kind"),
        _json_object(r[5], "unreadable_detail", "detail"),
    )


def sample(r: tuple[Any, ...]) -> SampleRecord:
    lat, lon = (None, None) if r[6] is None or r[7] is None else degrees(r[6], r[7])
    return SampleRecord(
        cast_id=integer(r[0], "a sample's cast"),
        mono_s=number(r[1], "mono_s"),
        wall_s=wall_time(r[2], "wall_s"),
        clock_synced=bool(r[3]),
        depth_m=number(r[4], "depth_m"),
        phase=text(r[5], "phase"),
        lat_deg=lat,
        lon_deg=lon,
    )


def _decoded(raw: int, order: str | None, stored: int | None) -> int | None:
    """The timestamp's two bytes (stored read big-endian) in the session's byte order."""
    if order == "little":
        return ((raw & 0xFF) << 8) | (raw >> 8)
    if order == "big":
        return raw
    return stored


def fix(row: tuple[Any, ...], orders: dict[int | None, str]) -> FixRecord:
    order = orders.get(row[0], row[12])
    raw = integer(row[5], "ap_timestamp_s")
    lat, lon = degrees(row[6], row[7])
    return FixRecord(
        session_id=optional_id(row[0], "a session"),
        mono_s=number(row[1], "mono_s"),
        wall_s=wall_time(row[2], "wall_s"),
        clock_synced=bool(row[3]),
        frame=text(row[4], "frame"),
        ap_timestamp_s=raw,
        lat_deg=lat,
        lon_deg=lon,
        alt_m=number(row[8], "alt_mm") / 1000.0,
        sonar_distance_m=number(row[9], "sonar_distance_mm") / 1000.0,
        sonar_confidence_pct=integer(row[10], "sonar_confidence_pct"),
        ap_time_s=_decoded(raw, order, optional_id(row[11], "ap_time_s")),
        ap_time_order=order if isinstance(order, str) or order is None else None,
    )
