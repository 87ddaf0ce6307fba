"""A real journal and a real status socket for the field page's tests."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from cc_daemon.config.sonde import DEFAULT_PARAMETERS
from cc_daemon.store import Journal, JournalReader
from cc_daemon.store.synthetic import FakeClock, write_survey
from tests.waitkit import until_sync

# What the daemon's status socket serves in the middle of a cast (status_report.py),
# plus a section no version of the page knows: it must still be shown.
STATUS: dict[str, Any] = {
    "daemon": {"state": "serving", "version": "0.1.0", "pid": 1, "host": "boat",
               "uptime_s": 12.0, "wall_time": 1_700_000_000.0},
    "link": {"up": True, "port": "/dev/serial0", "baudrate": 9600, "port_losses": 0,
             "open_attempts": 0},
    "fix": {"timestamp_s": 72, "lat_e7": -372605790, "lon_e7": 404506308, "alt_mm": 0,
            "sonar_distance_mm": 6000, "sonar_confidence_pct": 90, "age_s": 0.4},
    "cast": {"phase": "descending", "cast_id": 3, "planned_depth_m": 5.0, "depth_m": 1.25},
    "winch": {"backend": "sim", "depth_m": 1.25, "moving": True, "at_home": False,
              "fault": None},
    "journal": {"path": "/var/lib/cc-daemon/cc-daemon.db", "writable": True,
                "pending_rows": 2, "disk_free_bytes": 5_000_000_000},
    "counters": {"frames_in": 10, "frames_out": 9},
    "clock": {"synchronised": True, "max_error_s": 0.01, "source": "adjtimex", "detail": ""},
    "tide_gauge": {"level_m": 0.42},
}  # fmt: skip


def status(**changes: dict[str, Any]) -> dict[str, Any]:
    doc = copy.deepcopy(STATUS)
    for section, values in changes.items():
        doc[section] = {**doc.get(section, {}), **values}
    return doc


def make_journal(db: Path) -> Path:
    """Two surveys: a short one, then 30 minutes with casts every 10 minutes, the last
    measured cast with sonde readings (every default parameter) on its way down."""
    clock = FakeClock()
    for minutes in (5, 30):
        journal = Journal(db, monotonic=clock.monotonic, wall=clock.wall)
        journal.open()
        write_survey(journal, clock, duration_s=minutes * 60, cast_every_s=600)
        if minutes == 30:
            _sonde_readings(journal, db)  # in the survey's own session, as the daemon does
        journal.close()
        clock.advance(3600)
    return db


def _sonde_readings(journal: Journal, db: Path) -> None:
    until_sync(lambda: not journal.health().pending_rows, "the casts on disk (writer thread)")
    with JournalReader(db) as reader:
        cast = [c for c in reader.casts() if c.outcome == "completed"][-1]
    for i in range(8):
        depth = i * 0.5
        values: dict[str, float | None] = {p.name: None for p in DEFAULT_PARAMETERS}
        values.update(depth=depth, temperature=24.0 - depth)
        journal.record_sonde_sample(
            cast_id=cast.id, phase="descending", mono_s=cast.start_mono_s + i,
            wall_s=cast.start_wall_s + i, duration_s=0.08, status="ok", error=None,
            line_out_m=depth, sonde_depth_m=depth, values=values, missing={}, simulated=True,
        )  # fmt: skip
