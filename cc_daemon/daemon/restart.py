"""A restart after the daemon died mid-cast: say so, and free the boat.

The firmware waits at a station until `R-F`, with no timeout: a daemon killed
mid-cast leaves the boat there for ever. At start, after the journal marked
the cast `unfinished`, this journals `daemon_died` (the session that left no
`daemon_stopped`) and `cast_interrupted` (with the last depth journaled) and
hands the daemon the stations to release; the daemon (`casting`) sends `R-F`
for each once the link is up and the winch verifies home (its start-up homing
has run), else holds the station with `R-L`, and journals `cast_recovered`.
An `R-F` the firmware is not waiting for is harmless (docs/protocol.md).
Rows an earlier run could only put in spill files (its journal never came back)
are said too, with the files (`spill_files_left`): they are not in the journal.
"""

from __future__ import annotations

import contextlib

import structlog

from cc_daemon.store import Journal
from cc_daemon.store.interrupted import InterruptedCast, died_session, interrupted_casts

_log = structlog.get_logger("cc_daemon.service")


def note_interrupted(journal: Journal) -> list[InterruptedCast]:
    """Journal what the previous run left; the casts whose station to release."""
    try:
        died = died_session(journal.path)
        casts = interrupted_casts(journal.path, journal.recovered)
    except Exception:  # a journal that cannot be read must not stop the boat
        _log.error("could not read what the previous run left", exc_info=True)
        return []
    if died is not None:
        _log.error("the previous run died: no stop recorded", session_id=died.session_id)
        journal.record_event(
            "daemon_died",
            session_id=died.session_id,
            pid=died.pid,
            opened_wall_s=died.opened_wall_s,
        )
    _left_in_spill_files(journal)
    for cast in casts:
        depth = None if cast.last_depth_m is None else round(cast.last_depth_m, 3)
        _log.error(
            "cast interrupted by the previous run: its station will be released",
            cast_id=cast.cast_id,
            last_depth_m=depth,
        )
        journal.record_event(
            "cast_interrupted", cast_id=cast.cast_id, last_depth_m=depth, samples=cast.samples
        )
    return casts


def _left_in_spill_files(journal: Journal) -> None:
    """Rows an earlier run could only spill (its journal never came back before it
    ended): not in the journal. Said at start, at error and as an event, with where."""
    try:
        files = journal.leftover_spill_files()
    except Exception:
        _log.error("could not look for an earlier run's spill files", exc_info=True)
        return
    if not files:
        return
    lines = 0
    for path in files:  # counted as read, a block at a time: the files may be large
        with contextlib.suppress(OSError), path.open("rb") as file:
            lines += sum(block.count(b"\n") for block in iter(lambda: file.read(1 << 16), b""))
    paths = [str(path) for path in files]
    _log.error(
        "an earlier run left rows only in spill files, not in the journal: keep these "
        "files (JSON lines, one row each) with the survey's data",
        files=paths,
        rows=lines,
    )
    journal.record_event("spill_files_left", files=paths, rows=lines)
