"""`cc-daemon snapshot DEST`: a consistent, single-file copy of a journal being written."""

from __future__ import annotations

import argparse
import contextlib
import sqlite3
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from cc_daemon.cli import data as datacli
from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.store import Journal
from cc_daemon.store.snapshot import SnapshotReport, take_snapshot

REPO = Path(__file__).resolve().parent.parent
FIX = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)
STATION = StartMeasuring(73, -37260600, 404506400, 702000, 6500, 90)


def run(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="cc-daemon")
    datacli.add_commands(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    result: int = args.handler(args)
    return result


class Recorder:
    """The daemon's side: a real Journal recorded from one thread (its 'event loop')
    as fast as it goes, casts with their samples and fixes between them."""

    def __init__(self, db: Path) -> None:
        self.journal = Journal(db)
        self.journal.open()
        self.stop = threading.Event()
        self.casts = 0
        self.thread = threading.Thread(target=self._record, name="recorder")

    def _record(self) -> None:
        while not self.stop.is_set():
            cast_id = self.journal.start_cast(
                STATION, planned_depth_m=2.0, mode="continuous", plan={}
            )
            for i in range(20):
                self.journal.record_fix(FIX)
                self.journal.record_sample(cast_id, i * 0.1, "descending")
            self.journal.end_cast(cast_id, outcome="completed", reached_depth_m=1.9)
            self.journal.record_event("link_up", port="/dev/ttyAMA0")
            self.casts += 1
            self.stop.wait(0.002)

    def __enter__(self) -> Recorder:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(10)
        self.journal.close()


@pytest.fixture
def recording(tmp_path: Path) -> Iterator[tuple[Path, Recorder]]:
    db = tmp_path / "cc-daemon.db"
    with Recorder(db) as recorder:
        while committed_casts(db) < 3:  # some of it in the file before the first copy
            recorder.stop.wait(0.01)
        yield db, recorder


def committed_casts(db: Path) -> int:
    with contextlib.closing(sqlite3.connect(f"{db.as_uri()}?mode=ro", uri=True)) as conn:
        try:
            return int(conn.execute("SELECT count(*) FROM casts").fetchone()[0])
        except sqlite3.OperationalError:  # the writer has not made the tables yet
            return 0


def check_copy(report: SnapshotReport) -> None:
    """The copy is sound, one file, and holds what the report says."""
    path = report.path
    assert not Path(f"{path}-wal").exists() and not Path(f"{path}-journal").exists()
    assert path.read_bytes()[18:20] == b"\x01\x01"  # rollback journal: no -wal needed
    with sqlite3.connect(f"{path.as_uri()}?immutable=1", uri=True) as conn:
        assert conn.execute("PRAGMA integrity_check").fetchone() == ("ok",)
        counts = [
            conn.execute(f"SELECT count(*) FROM {t}").fetchone()[0]
            for t in ("casts", "samples", "fixes", "events")
        ]
        assert counts == [report.casts, report.samples, report.fixes, report.events]
        orphans = conn.execute(
            "SELECT count(*) FROM samples WHERE cast_id NOT IN (SELECT id FROM casts)"
        ).fetchone()[0]
        assert orphans == 0
    conn.close()


def test_snapshots_of_a_journal_being_written_are_consistent(
    recording: tuple[Path, Recorder], tmp_path: Path
) -> None:
    db, recorder = recording
    reports = [take_snapshot(db, tmp_path / f"copy-{n}.db") for n in range(4)]
    for report in reports:
        check_copy(report)
        assert report.casts >= 3 and report.samples >= 20 * 2  # the third may be under way
        assert report.first_wall_s is not None and report.last_wall_s is not None
        assert report.first_wall_s <= report.last_wall_s
    # Later copies hold at least as much: each is one moment of a growing file.
    assert [r.samples for r in reports] == sorted(r.samples for r in reports)
    assert recorder.thread.is_alive()  # the daemon's side never noticed


def test_the_command_copies_reports_and_never_overwrites(
    recording: tuple[Path, Recorder], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    db, _ = recording
    dest = tmp_path / "off-the-boat.db"
    assert run("snapshot", str(dest), "--db", str(db)) == 0
    out = capsys.readouterr()
    assert out.err == f"reading {db}\n"
    assert out.out.startswith(f"copied {db} to {dest}: ")
    assert " casts, " in out.out and " samples, " in out.out and " fixes, " in out.out
    assert " to " in out.out.split("; ")[1]  # the time span
    before = dest.read_bytes()
    assert run("snapshot", str(dest), "--db", str(db)) == 2
    assert capsys.readouterr().err.endswith(
        f"cc-daemon snapshot: {dest} exists: refusing to overwrite it\n"
    )
    assert dest.read_bytes() == before
    # A directory gets a dated copy inside it.
    usb = tmp_path / "usb"
    usb.mkdir()
    assert run("snapshot", str(usb), "--db", str(db)) == 0
    [copy] = usb.iterdir()
    assert copy.name.startswith("cc-daemon-snapshot-") and copy.suffix == ".db"
    assert f"to {copy}: " in capsys.readouterr().out


def test_no_journal_no_copy(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dest = tmp_path / "copy.db"
    assert run("snapshot", str(dest), "--db", str(tmp_path / "none.db")) == 1
    assert "no journal at" in capsys.readouterr().err
    assert not dest.exists()


def test_the_real_command_line_beside_a_writing_daemon(
    recording: tuple[Path, Recorder], tmp_path: Path
) -> None:
    db, _ = recording
    dest = tmp_path / "copy.db"
    done = subprocess.run(
        [sys.executable, "-m", "cc_daemon", "snapshot", str(dest), "--db", str(db)],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"copied {db} to {dest}: ")
    with sqlite3.connect(f"{dest.as_uri()}?immutable=1", uri=True) as conn:
        assert conn.execute("PRAGMA quick_check").fetchone() == ("ok",)
    conn.close()
