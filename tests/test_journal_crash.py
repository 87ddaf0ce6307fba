"""`kill -9` mid-cast: every sample older than a second is in the file, and the
cast is marked unfinished when the journal is opened again."""

from __future__ import annotations

import contextlib
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from structlog.testing import capture_logs

from cc_daemon.store import Journal
from cc_daemon.store.journal import UNFINISHED_REASON

# The writer: a cast recorded as the daemon does, a sample and a fix every
# 50 ms (twenty times the real rate, to have many rows at risk), each line
# printed only after the call returned, with the system-wide monotonic time.
WRITER = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from cc_daemon.core.protocol import StartMeasuring, Telemetry
    from cc_daemon.store import Journal

    journal = Journal(Path(sys.argv[1]))
    journal.open()
    old = journal.start_cast(
        StartMeasuring(1, 0, 0, 0, 9000, 100), planned_depth_m=1, mode="continuous", plan={}
    )
    journal.end_cast(old, outcome="completed", reached_depth_m=1.0)
    station = StartMeasuring(72, -37260579, 404506308, 702385, 8219, 100)
    cast_id = journal.start_cast(station, planned_depth_m=5.0, mode="continuous", plan={})
    print("cast", cast_id, flush=True)
    i = 0
    while True:
        i += 1
        journal.record_sample(cast_id, i / 100, "descending")
        journal.record_fix(Telemetry(i, -37260579, 404506308, 702385, 8219, 100))
        print("row", i, time.monotonic(), flush=True)
        time.sleep(0.05)
    """
)


def _times(lines: list[str]) -> list[float]:
    """The times of the rows the child said it recorded ("row i t" lines)."""
    return [float(w[2]) for w in (ln.split() for ln in lines) if len(w) == 3]


def test_kill_9_mid_cast_loses_no_sample_older_than_a_second(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    child = subprocess.Popen(
        [sys.executable, str(script), str(db)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert child.stdout is not None
        first = child.stdout.readline().split()
        assert first[0] == "cast", first
        cast_id = int(first[1])
        # Until 30 rows are more than a second old (about 2.5 s on an idle machine; a
        # loaded one writes them slower), read as the child prints them.
        lines: list[str] = []
        deadline = time.monotonic() + 120
        while sum(1 for at in _times(lines) if at < time.monotonic() - 1.0) < 30:
            assert time.monotonic() < deadline, lines[-3:]
            lines.append(child.stdout.readline())
        killed_at = time.monotonic()
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=30)
        lines += child.stdout.read().split("\n")
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        if child.stdout is not None:
            child.stdout.close()
    recorded = [(int(w[1]), float(w[2])) for w in (ln.split() for ln in lines) if len(w) == 3]
    old_enough = {i for i, at in recorded if at < killed_at - 1.0}
    assert len(old_enough) >= 30  # ~2 s of rows at 20 a second, or the test proves little

    # Read the file as it was left, before any journal opens it again.
    with contextlib.closing(sqlite3.connect(db)) as conn:
        stored = {round(d * 100) for (d,) in conn.execute("SELECT depth_m FROM samples")}
        fixes = {t for (t,) in conn.execute("SELECT ap_timestamp_s FROM fixes")}
        outcome = conn.execute("SELECT outcome FROM casts WHERE id = ?", (cast_id,)).fetchone()
    assert old_enough <= stored, sorted(old_enough - stored)
    # Telemetry may lag by up to 10 s by the rule; it is committed every
    # second, so anything two seconds old must be there.
    assert {i for i, at in recorded if at < killed_at - 2.0} <= fixes
    assert outcome == (None,)  # nobody closed the cast

    journal = Journal(db)
    with capture_logs() as logs:
        recovered = journal.open()
    journal.close()
    assert recovered == [cast_id]
    (warning,) = [e for e in logs if e["log_level"] == "warning"]
    assert warning["cast_id"] == cast_id
    assert warning["samples"] == len(stored)
    with contextlib.closing(sqlite3.connect(db)) as conn:
        rows = conn.execute("SELECT id, outcome, reached_depth_m, reason FROM casts ORDER BY id")
        assert rows.fetchall() == [
            (1, "completed", 1.0, None),
            (cast_id, "unfinished", max(stored) / 100, UNFINISHED_REASON),
        ]

    again = Journal(db)  # a second opening finds nothing left to mark
    assert again.open() == []
    again.close()
