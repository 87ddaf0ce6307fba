"""Surveys: the journal's unit of data a person asks for.

A survey is one daemon session (one run of `cc-daemon`, of `--simulate`, of the
service between two starts): its casts, fixes, sonde readings and events share
the session's id. Every run appends to the same journal, so the data commands
read the latest survey unless told `--survey N` or `--survey all`. A session
that recorded nothing (a start that failed, a daemon that heard no autopilot)
is not a survey.

It never opens the file nor runs a query itself: `store.reader` runs `QUERY`
(within its bounds) and hands each row to `record`.
"""

from collections.abc import Sequence
from typing import Any, NamedTuple

from cc_daemon.store import stations as station_rules
from cc_daemon.store.values import dated, integer, wall_time

ALL = "all"
LATEST = "latest"


class SurveyRecord(NamedTuple):
    id: int  # the session's id
    start_wall_s: float
    end_wall_s: float  # the last row recorded
    stations: int  # `store.stations`: the plan's, else those asked, skipped or measured
    measured: int  # stations where a cast completed
    fixes: int
    simulated: bool | None  # None: not recorded (a journal older than version 4)
    winch_backend: str | None
    castable: int = 0  # stations that could be cast at (not a shoal)


QUERY = f"""
SELECT s.id, s.opened_wall_s, s.simulated, s.winch_backend,
    (SELECT count(*) FROM casts c WHERE c.session_id = s.id),
    (SELECT count(*) FROM casts c WHERE c.session_id = s.id AND c.outcome = 'completed'),
    (SELECT count(*) FROM fixes f WHERE f.session_id = s.id),
    (SELECT max({dated("f.wall_s")}) FROM fixes f WHERE f.session_id = s.id),
    (SELECT max({dated("coalesce(c.end_wall_s, c.start_wall_s)")})
        FROM casts c WHERE c.session_id = s.id)
FROM sessions s ORDER BY s.id
"""


def record(row: tuple[Any, ...]) -> SurveyRecord | None:
    """One row of `QUERY` as a survey; None for a session that recorded nothing.
    ValueError if its start cannot be a time (the reader skips and counts it)."""
    sid, opened, simulated, backend, stations, measured, fixes, last_fix, last_cast = row
    if not stations and not fixes:
        return None
    start = wall_time(opened, "a survey's start")
    ends = [t for t in (last_fix, last_cast) if t is not None]
    return SurveyRecord(
        id=integer(sid, "a survey's number"),
        start_wall_s=start,
        end_wall_s=max(ends) if ends else start,
        stations=stations,
        measured=measured,
        fixes=fixes,
        simulated=None if simulated is None else bool(simulated),
        winch_backend=backend if isinstance(backend, str) else None,
    )


def counted(
    survey: SurveyRecord,
    places: Sequence[station_rules.Place],
    plan: Sequence[station_rules.PlannedStation] | None,
) -> SurveyRecord:
    """`survey` with its stations counted by `store.stations` (one count everywhere)."""
    found = station_rules.counts(station_rules.stations(places, plan))
    return survey._replace(
        stations=found.stations, castable=found.castable, measured=found.measured
    )


def choose_survey(
    surveys: list[SurveyRecord], choice: str | int, path: object
) -> SurveyRecord | None:
    """The survey `choice` names among `surveys` (`all`, or `latest` of none: None);
    StoreError naming the file's surveys if there is no such one."""
    from cc_daemon.store.schema import StoreError

    if choice == ALL or (choice == LATEST and not surveys):
        return None
    if choice == LATEST:
        return surveys[-1]
    found = [s for s in surveys if s.id == choice]
    if not found:
        known = ", ".join(str(s.id) for s in surveys) or "none"
        raise StoreError(f"no survey {choice} in {path} (surveys: {known})")
    return found[0]


def parse_survey(text: str) -> str | int:
    """`--survey`'s value: a survey's number, `all` or `latest`; ValueError otherwise."""
    word = text.strip().lower()
    if word in (ALL, LATEST):
        return word
    try:
        number = int(word)
    except ValueError:
        raise ValueError(f"{text!r}: a survey's number, 'all' or 'latest'") from None
    if number < 1:
        raise ValueError(f"{text!r}: survey numbers start at 1")
    return number
