"""The journal never loses a row quietly (issue 20): spill files, replay, status, modes.

A journal whose file fails for longer than `SPILL_AFTER_S` moves its rows to a
spill file on a filesystem that still works and writes them into the journal,
oldest first, once it takes rows again. The real cases run on a real ext4
filesystem (a loop device, in a private mount namespace) that turns itself
read-only after an I/O error as an SD card's does, and one that is frozen.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sqlite3
import stat
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import structlog

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.daemon.restart import note_interrupted
from cc_daemon.store import Journal, spillover
from tests.journalkit import full_journal

FIX = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)
STATION = StartMeasuring(73, -37260600, 404506400, 702000, 6500, 90)
REPO = Path(__file__).resolve().parent.parent
UNSHARE = ("unshare", "-m", "--propagation", "private")  # mounts seen by the test only


def query(path: Path, sql: str) -> list[tuple[object, ...]]:
    with contextlib.closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as conn:
        return conn.execute(sql).fetchall()


def wait_for(predicate: Callable[[], bool], timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"condition not met within {timeout} s")
        time.sleep(0.01)


def record_cast(journal: Journal, samples: int = 5) -> int:
    cast_id = journal.start_cast(STATION, planned_depth_m=2, mode="continuous", plan={})
    for i in range(samples):
        journal.record_sample(cast_id, i / 2, "descending")
        journal.record_fix(FIX._replace(timestamp_s=i))
    journal.end_cast(cast_id, outcome="completed", reached_depth_m=2.0)
    return cast_id


def test_a_long_failure_spills_the_rows_and_replays_them_in_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(spillover, "SPILL_AFTER_S", 0.2)
    db = tmp_path / "j.db"
    journal, disk = full_journal(db)
    try:
        journal.open()
        for i in range(600):  # fills the last free pages: the rest must wait
            journal.record_fix(FIX._replace(timestamp_s=1000 + i))
        wait_for(lambda: journal.health().spilled_rows > 0)
        first = record_cast(journal)
        second = record_cast(journal, samples=3)
        journal.record_event("port_lost", port="/dev/ttyUSB0")

        # Every pending row is in a spill file beside the journal; none in memory only.
        def all_spilled() -> bool:
            health = journal.health()
            return health.spilled_rows == health.pending_rows

        wait_for(all_spilled)
        health = journal.health()
        assert not health.writable
        assert "full" in (health.last_error or "")
        assert health.dropped_rows == 0
        (spill,) = health.spill_files
        assert spill.parent == tmp_path
        assert stat.S_IMODE(spill.stat().st_mode) == 0o640
        # The casts fitted in the last free pages (they go before older telemetry);
        # the telemetry that did not waits in the spill file, not in memory.
        lines = [json.loads(line) for line in spill.read_text().splitlines()]
        assert {line["table"] for line in lines} == {"fixes"}
        assert query(db, "SELECT count(*) FROM casts") == [(2,)]
        disk.full = False
        # The writer clears its error and removes the spill file just after the pass
        # that wrote the rows: wait for the whole recovery, then check each part.
        wait_for(
            lambda: (
                (h := journal.health()).pending_rows == 0
                and h.last_error is None
                and h.spill_files == ()
            )
        )
        health = journal.health()
        assert health.writable
        assert health.last_error is None
        assert health.spill_files == ()
    finally:
        journal.close()
    assert not spill.exists()
    assert journal.health().dropped_rows == 0
    assert query(db, "SELECT id, outcome FROM casts ORDER BY id") == [
        (first, "completed"),
        (second, "completed"),
    ]
    assert query(db, "SELECT cast_id, count(*) FROM samples GROUP BY cast_id") == [
        (first, 5),
        (second, 3),
    ]
    stamps = [t for (t,) in query(db, "SELECT ap_timestamp_s FROM fixes ORDER BY id")]
    # Every fix once; the spilled ones in the order they came (a few newer ones
    # that fitted while 500 older ones did not may stand before them).
    assert [t for t in stamps if t >= 1000] == list(range(1000, 1600))
    assert sorted(t for t in stamps if t < 1000) == [0, 0, 1, 1, 2, 2, 3, 4]
    kinds = [k for (k,) in query(db, "SELECT kind FROM events ORDER BY id")]
    assert kinds == ["port_lost", "journal_unwritable"]


def test_a_new_journal_and_its_side_files_get_the_mode_whatever_the_umask(
    tmp_path: Path,
) -> None:
    old = os.umask(0o002)  # a hand run with a loose umask: 0664 without the rule
    try:
        with Journal(tmp_path / "j.db") as journal:
            record_cast(journal)
            wait_for(lambda: journal.health().pending_rows == 0)
            modes = {
                p.name: stat.S_IMODE(p.stat().st_mode) for p in tmp_path.iterdir() if p.is_file()
            }
        with Journal(tmp_path / "k.db", file_mode=0o600) as other:
            other.record_event("x")
            wait_for(lambda: other.health().pending_rows == 0)
            own = stat.S_IMODE((tmp_path / "k.db").stat().st_mode)
    finally:
        os.umask(old)
    assert modes == {"j.db": 0o640, "j.db-wal": 0o640, "j.db-shm": 0o640}
    assert own == 0o600


# ------------------------------------------------ a real filesystem failing

SCRIPT = textwrap.dedent(
    """
    import json, os, subprocess, sys, time
    from pathlib import Path
    from cc_daemon.core.protocol import StartMeasuring, Telemetry
    from cc_daemon.store import Journal, spillover

    spillover.SPILL_AFTER_S = 0.3
    spillover.STALL_S = 1.0
    work, case = Path(sys.argv[1]), sys.argv[2]
    card = work / "card"
    card.mkdir()
    subprocess.run(["mount", "-o", "loop,errors=remount-ro", str(work / "card.img"), str(card)],
                   check=True)
    dev = Path(subprocess.run(["findmnt", "-no", "SOURCE", str(card)], check=True,
                              capture_output=True, text=True).stdout.strip()).name
    FIX = Telemetry(72, -37260579, 404506308, 702385, 8219, 100)
    STATION = StartMeasuring(73, -37260600, 404506400, 702000, 6500, 90)
    out = {}

    def wait(pred, timeout=30.0):
        end = time.monotonic() + timeout
        while not pred():
            if time.monotonic() > end:
                raise SystemExit("timed out: " + json.dumps(out, default=str))
            time.sleep(0.02)

    def cast(j):
        cid = j.start_cast(STATION, planned_depth_m=2, mode="continuous", plan={})
        for i in range(5):
            j.record_sample(cid, i / 2, "descending")
            j.record_fix(FIX._replace(timestamp_s=i))
        j.end_cast(cid, outcome="completed", reached_depth_m=2.0)

    j = Journal(card / "j.db")
    j.open()
    cast(j)
    wait(lambda: j.health().pending_rows == 0)
    if case == "readonly":
        # What ext4 does after an I/O error on an SD card: it turns itself read-only.
        (Path("/sys/fs/ext4") / dev / "trigger_fs_error").write_text("test")
        cast(j)
        cast(j)
        def all_spilled():
            h = j.health()
            return h.spilled_rows > 0 and h.spilled_rows == h.pending_rows
        wait(all_spilled)
        h = j.health()
        out["during"] = {"writable": h.writable, "error": h.last_error,
                         "spill_files": [str(p) for p in h.spill_files],
                         "spilled": h.spilled_rows}
        j.close()
        out["dropped"] = j.health().dropped_rows
    else:
        subprocess.run(["fsfreeze", "-f", str(card)], check=True)
        try:
            j.record_event("port_lost", port="/dev/ttyUSB0")
            wait(lambda: not j.health().writable)
            h = j.health()
            out["during"] = {"writable": h.writable, "error": h.last_error}
        finally:
            subprocess.run(["fsfreeze", "-u", str(card)], check=True)
        wait(lambda: j.health().writable and j.health().pending_rows == 0)
        out["after"] = {"error": j.health().last_error}
        j.close()
    db = "file:" + str(card / "j.db") + "?mode=ro"
    import sqlite3
    conn = sqlite3.connect(db, uri=True)
    out["casts"] = conn.execute("SELECT count(*) FROM casts").fetchone()[0]
    conn.close()
    print(json.dumps(out))
    """
)


def _run_on_ext4(tmp_path: Path, case: str) -> dict[str, object]:
    if os.geteuid() != 0 or not all(shutil.which(t) for t in ("unshare", "mkfs.ext4")):
        pytest.skip("needs root, unshare and mkfs.ext4 for a loop-mounted ext4")
    image = tmp_path / "card.img"
    with image.open("wb") as f:
        f.truncate(16 << 20)
    subprocess.run(["mkfs.ext4", "-q", "-F", str(image)], check=True)
    run = tmp_path / "run"
    run.mkdir()
    env = {**os.environ, "PYTHONPATH": str(REPO), "RUNTIME_DIRECTORY": str(run)}
    env.pop("STATE_DIRECTORY", None)
    done = subprocess.run(
        [
            "unshare",
            "-m",
            "--propagation",
            "private",
            sys.executable,
            "-c",
            SCRIPT,
            str(tmp_path),
            case,
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
        check=False,
    )
    if done.returncode != 0 and "failed to setup loop device" in done.stderr:
        pytest.skip(f"no loop devices here: {done.stderr.strip()[-200:]}")
    assert done.returncode == 0, done.stderr[-3000:]
    result: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    result["log"] = done.stdout + done.stderr
    return result


def test_an_sd_card_turning_read_only_mid_run_loses_no_cast(tmp_path: Path) -> None:
    result = _run_on_ext4(tmp_path, "readonly")
    during = result["during"]
    assert isinstance(during, dict)
    assert during["writable"] is False
    assert "readonly" in during["error"] or "Read-only" in during["error"]
    # Casts 2 and 3 went to the runtime directory (the card was read-only), and stay there.
    (spill,) = during["spill_files"]
    assert Path(spill).parent == tmp_path / "run"
    lines = [json.loads(line) for line in Path(spill).read_text().splitlines()]
    assert [r["table"] for r in lines].count("casts") == 2
    assert [r["table"] for r in lines].count("samples") == 10
    assert result["dropped"] == 0
    assert result["casts"] == 1  # cast 1, committed before the card failed
    # Said at error level, naming the file.
    assert "rows saved to a spill file" in str(result["log"])


def test_a_frozen_filesystem_shows_as_not_writable_until_it_thaws(tmp_path: Path) -> None:
    result = _run_on_ext4(tmp_path, "frozen")
    during = result["during"]
    assert isinstance(during, dict)
    assert during["writable"] is False
    assert "frozen" in during["error"]
    assert result["after"] == {"error": None}
    assert result["casts"] == 1


def test_an_earlier_runs_spill_files_are_said_at_start(tmp_path: Path) -> None:
    db = tmp_path / "j.db"
    with Journal(db):
        pass
    left = tmp_path / "j-unwritten-20261125T101500Z.jsonl"
    left.write_text('{"table": "fixes", "row": [1]}\n' * 3)
    (tmp_path / "other-unwritten-20261125T101500Z.jsonl").write_text("{}\n")  # not ours
    with Journal(db) as journal, structlog.testing.capture_logs() as logs:
        assert journal.leftover_spill_files() == [left]
        note_interrupted(journal)
    [said] = [e for e in logs if str(e["event"]).startswith("an earlier run left rows only")]
    assert said["log_level"] == "error" and said["files"] == [str(left)] and said["rows"] == 3
    [(detail,)] = query(db, "SELECT detail_json FROM events WHERE kind = 'spill_files_left'")
    assert json.loads(str(detail)) == {"files": [str(left)], "rows": 3}
    assert left.exists()  # kept: its rows are nowhere else
