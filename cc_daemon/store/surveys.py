"""Surveys: the journal's unit of data a person asks for.

A survey is one daemon session (one run of `cc-daemon`, of `--simulate`, of the
service between two starts): its casts, fixes, sonde readings and events share
the session's id. Every run appends to the same journal, so the data commands
read the latest survey unless told `--survey N` or `--survey all`. A session
that recorded nothing (a start that failed, a daemon that heard no autopilot)
is not a survey.

It only reads, and never opens the file itself.
"""

import sqlite3
from typing import NamedTuple

ALL = "all"
LATEST = "latest"


class SurveyRecord(NamedTuple):
    id: int  # the session's id
    start_wall_s: float
    end_wall_s: float  # the last row recorded
    stations: int  # casts journaled: one per station, skipped or measured
    measured: int  # casts completed
    fixes: int
    simulated: bool | None  # None: not recorded (a journal older than version 4)
    winch_backend: str | None


_SURVEYS = """
SELECT s.id, s.opened_wall_s, s.simulated, s.winch_backend,
    (SELECT count(*) FROM casts c WHERE c.session_id = s.id),
    (SELECT count(*) FROM casts c WHERE c.session_id = s.id AND c.outcome = 'completed'),
    (SELECT count(*) FROM fixes f WHERE f.session_id = s.id),
    (SELECT max(f.wall_s) FROM fixes f WHERE f.session_id = s.id),
    (SELECT max(coalesce(c.end_wall_s, c.start_wall_s)) FROM casts c WHERE c.session_id = s.id)
FROM sessions s ORDER BY s.id
"""


def list_surveys(conn: sqlite3.Connection) -> list[SurveyRecord]:
    """Every session that recorded a fix or a cast, oldest first."""
    out = []
    for (
        sid,
        opened,
        simulated,
        backend,
        stations,
        measured,
        fixes,
        last_fix,
        last_cast,
    ) in conn.execute(_SURVEYS):
        if not stations and not fixes:
            continue
        ends = [t for t in (last_fix, last_cast) if t is not None]
        out.append(
            SurveyRecord(
                id=sid,
                start_wall_s=opened,
                end_wall_s=max(ends) if ends else opened,
                stations=stations,
                measured=measured,
                fixes=fixes,
                simulated=None if simulated is None else bool(simulated),
                winch_backend=backend,
            )
        )
    return out


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
