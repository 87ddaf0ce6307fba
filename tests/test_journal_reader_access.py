"""The data commands read a journal in a directory they may not write.

The daemon's state directory belongs to the daemon (`StateDirectoryMode=0750`);
a user in its group may read the journal but not create SQLite's `-shm` file
beside it. As root the test drops to `nobody` in a subprocess (after importing,
since the interpreter may live where `nobody` cannot read); as any other user
it makes the directory read-only for itself.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.store import Journal, JournalReader

FIX = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)
STATION = StartMeasuring(73, -37260600, 404506400, 702000, 6500, 90)
NOBODY = 65534
EXPECTED = {"casts": [[1, "completed"], [2, "aborted"]], "samples": 6, "fixes": 30, "events": 1}

READ_AS_NOBODY = textwrap.dedent(
    """
    import json, os, sys
    from pathlib import Path
    from cc_daemon.store import JournalReader, StoreError
    import cc_daemon.store.damage  # loaded lazily by the reader: load it while readable

    os.setgroups([])
    os.setgid(int(sys.argv[2]))
    os.setuid(int(sys.argv[2]))
    try:
        with JournalReader(Path(sys.argv[1])) as reader:
            print(json.dumps({
                "casts": [[c.id, c.outcome] for c in reader.casts()],
                "samples": len(reader.samples()),
                "fixes": len(reader.fixes()),
                "events": len(reader.events()),
            }))
    except StoreError as exc:
        print(json.dumps({"error": str(exc)}))
    """
)


def record(journal: Journal) -> None:
    for i in range(30):
        journal.record_fix(FIX._replace(timestamp_s=i))
    for outcome in ("completed", "aborted"):
        cast_id = journal.start_cast(STATION, planned_depth_m=1, mode="continuous", plan={})
        for depth in (0.25, 0.5, 0.75):
            journal.record_sample(cast_id, depth, "descending")
        journal.end_cast(cast_id, outcome=outcome, reached_depth_m=0.75)
    journal.record_event("port_lost", port="/dev/ttyUSB0")


@pytest.fixture
def state_dir() -> Iterator[Path]:
    """A directory `nobody` can enter (pytest's own temporary tree is private to root)."""
    top = Path(tempfile.mkdtemp(prefix="cc-daemon-test-"))
    top.chmod(0o755)
    state = top / "state"
    state.mkdir(mode=0o755)
    try:
        yield state
    finally:
        state.chmod(0o755)
        shutil.rmtree(top)


def read_without_write_access(db: Path) -> dict[str, object]:
    """What a user who may read `db` but not write its directory gets from the reader."""
    db.chmod(0o644)
    for extra in (Path(f"{db}-wal"), Path(f"{db}-shm")):
        if extra.exists():
            extra.chmod(0o644)
    if os.geteuid() == 0:
        script = db.parent.parent / "read_as_nobody.py"
        script.write_text(READ_AS_NOBODY)
        script.chmod(0o644)
        done = subprocess.run(
            [sys.executable, str(script), str(db), str(NOBODY)],
            capture_output=True,
            text=True,
            check=False,
            timeout=30,
            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent)},
        )
        if done.returncode != 0 and "PermissionError" in done.stderr and "setuid" in done.stderr:
            pytest.skip("cannot drop to an unprivileged user here")
        assert done.returncode == 0, done.stderr
        result: dict[str, object] = json.loads(done.stdout)
        return result
    db.parent.chmod(0o555)
    try:
        probe = db.parent / ".probe"
        try:
            probe.touch()
        except PermissionError:
            pass
        else:
            probe.unlink()
            pytest.skip("cannot make a directory read-only for this user")
        with JournalReader(db) as reader:
            return {
                "casts": [[c.id, c.outcome] for c in reader.casts()],
                "samples": len(reader.samples()),
                "fixes": len(reader.fixes()),
                "events": len(reader.events()),
            }
    finally:
        db.parent.chmod(0o755)


def test_a_journal_the_daemon_closed_cleanly(state_dir: Path) -> None:
    db = state_dir / "cc-daemon.db"
    with Journal(db) as journal:
        record(journal)
    assert sorted(p.name for p in state_dir.iterdir()) == ["cc-daemon.db"]  # no -wal, no -shm
    before = db.read_bytes()
    assert read_without_write_access(db) == EXPECTED
    assert db.read_bytes() == before
    assert sorted(p.name for p in state_dir.iterdir()) == ["cc-daemon.db"]


def test_a_journal_with_a_write_ahead_log_left_beside_it(state_dir: Path) -> None:
    # The daemon was killed: its last rows are only in the -wal, and no -shm is left.
    live = state_dir.parent / "live.db"
    journal = Journal(live)
    try:
        journal.open()
        record(journal)
        deadline = time.monotonic() + 60  # only a hang reaches it
        while journal.health().pending_rows:
            assert time.monotonic() < deadline, "the journal did not write its rows"
            time.sleep(0.01)
        db = state_dir / "cc-daemon.db"
        shutil.copyfile(live, db)
        shutil.copyfile(f"{live}-wal", f"{db}-wal")
    finally:
        journal.close()
    assert Path(f"{db}-wal").stat().st_size > 0
    wal_before = Path(f"{db}-wal").read_bytes()
    assert read_without_write_access(db) == EXPECTED
    assert Path(f"{db}-wal").read_bytes() == wal_before
    assert not Path(f"{db}-shm").exists()
