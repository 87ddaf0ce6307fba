"""Reading what `store.stations` names and counts from: each survey's casts as places,
and a simulated survey's plan.

The plan (the `stations_planned` event a simulation records) is looked for among
its session's first `stations.PLAN_WITHIN` events, found by rowid seeks: the
events table has no index but its rowid, and no question the field page asks on
a timer may read it whole. Events are appended session after session, so a
session's first is found by bisection. Only a simulated session is looked at:
nothing else records a plan.

`first_events` serves any question about how a session began (the sonde's
register map, for the field page's last reading) the same way.

It runs its queries through the reader it is given (`JournalReader.rows`, within
the reader's bounds) and never opens or writes a file itself.
"""

from __future__ import annotations

from typing import Any, Protocol

from cc_daemon.store import records, stations, values


class Rows(Protocol):
    """What is asked of the reader: `JournalReader.rows`, within its bounds."""

    def rows(self, sql: str, what: str, params: Any = ()) -> list[tuple[Any, ...]]: ...


Places = dict[int | None, list[stations.Place]]
Plans = dict[int | None, list[stations.PlannedStation]]


def places_and_plans(reader: Rows, survey: int | None) -> tuple[Places, Plans]:
    """Each survey's casts as places, and its plan where the journal holds one; of
    survey `survey` only, unless it is None."""
    where, params = ("", []) if survey is None else (" WHERE session_id = ?", [survey])
    places: Places = {}
    rows = reader.rows(
        f"SELECT session_id, id, lat_e7, lon_e7, outcome FROM casts{where} ORDER BY id",
        "casts",
        params,
    )
    for session, cast_id, lat_e7, lon_e7, outcome in rows:
        try:
            lat, lon = records.degrees(lat_e7, lon_e7)
            ended = outcome if isinstance(outcome, str) else None
            place = stations.Place(values.integer(cast_id, "a cast's id"), lat, lon, ended)
        except (TypeError, ValueError, ArithmeticError):
            continue  # `casts()` skips it too, and counts it
        places.setdefault(session, []).append(place)
    plans: Plans = {}
    for session in _simulated_sessions(reader, survey):
        plan = _plan(reader, session)
        if plan is not None:
            plans[session] = plan
    return places, plans


def _simulated_sessions(reader: Rows, survey: int | None) -> list[int]:
    where, params = ("", []) if survey is None else (" AND id = ?", [survey])
    rows = reader.rows(
        f"SELECT id FROM sessions WHERE simulated = 1{where} ORDER BY id", "the surveys", params
    )
    return [row[0] for row in rows if isinstance(row[0], int)]


def first_events(reader: Rows, session: int, limit: int) -> list[tuple[str, Any]]:
    """The (kind, detail JSON text) of session `session`'s first `limit` events, found
    by rowid seeks without reading the events table whole."""
    (bounds,) = reader.rows("SELECT min(id), max(id) FROM events", "events")
    low, high = bounds
    if not isinstance(low, int) or not isinstance(high, int):
        return []
    high += 1
    while low < high:  # the first event id whose session is `session` or a later one
        middle = (low + high) // 2
        found = reader.rows(
            "SELECT session_id FROM events WHERE id >= ? ORDER BY id LIMIT 1", "events", (middle,)
        )
        if found and isinstance(found[0][0], int) and found[0][0] < session:
            low = middle + 1
        else:
            high = middle
    rows = reader.rows(
        "SELECT session_id, kind, detail_json FROM events WHERE id >= ? ORDER BY id LIMIT ?",
        "events",
        (low, limit),
    )
    return [(kind, detail) for owner, kind, detail in rows if owner == session]


def _plan(reader: Rows, session: int) -> list[stations.PlannedStation] | None:
    for kind, detail in first_events(reader, session, stations.PLAN_WITHIN):
        if kind == stations.PLAN_EVENT:
            try:
                return stations.read_plan(values.json_value(detail))
            except ValueError:
                return None
    return None
