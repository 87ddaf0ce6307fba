"""A damaged journal is salvaged once per change of the file, not once per request; its
check runs once per change; and the copies never outlive the process (issue 27).

The field page opens a `JournalReader` for every request (`cli/web/journaldata.py`).
Measured by what the kernel counts for this process (`/proc/self/io`: bytes read and
written through system calls), not by timing: a second request on a damaged journal
writes no new copy, and one on a sound journal does not read the whole file again
for SQLite's check until the file changes. The copies live in one private
directory that the process removes at its end, and that the next process sweeps
away if this one was killed.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from cc_daemon.cli.web import journaldata
from cc_daemon.store import JournalReader, StoreError
from tests.hostilekit import REPO, run_command
from tests.journalkit import DAMAGE, sql, survey_journal


def io_counts() -> tuple[int, int]:
    """(bytes read, bytes written) by this process's system calls so far."""
    fields = dict(
        line.split(": ") for line in Path("/proc/self/io").read_text().splitlines() if line
    )
    return int(fields["rchar"]), int(fields["wchar"])


def ask_the_page(db: Path) -> list[str]:
    """What an open page asks of the journal, as the page's server reads it; what it was
    told of the journal's damage (the page's 503s)."""
    told = []
    for ask in (
        lambda: journaldata.surveys(db),
        lambda: journaldata.events(db, None),
        lambda: journaldata.latest(db, 1_717_230_000.0),
        lambda: journaldata.cast_profile(db, 2),
    ):
        try:
            ask()
        except StoreError as exc:  # a damaged journal: the page says so (a 503)
            told.append(str(exc))
    return told


@pytest.fixture
def damaged(tmp_path: Path) -> Path:
    db = tmp_path / "survey.db"
    survey_journal(db, casts=17)
    DAMAGE["garbled-page"](db)
    return db


def test_a_damaged_journal_is_salvaged_once_for_every_request_until_it_changes(
    damaged: Path,
) -> None:
    size = damaged.stat().st_size
    _, written = io_counts()
    assert all("is damaged" in said for said in ask_the_page(damaged))
    _, first = io_counts()
    assert first - written >= size  # the salvaged copy
    for _ in range(3):
        ask_the_page(damaged)
    _, later = io_counts()
    assert later - first < size // 4  # twelve more requests: no new copy
    sql(damaged, "UPDATE sessions SET software = 'changed'")  # a new state: a new salvage
    ask_the_page(damaged)
    _, changed = io_counts()
    assert changed - later >= size


def test_sqlites_check_reads_the_whole_file_once_per_change(tmp_path: Path) -> None:
    db = tmp_path / "survey.db"
    survey_journal(db, casts=3)
    # Room the page's questions never read, all of which SQLite's check reads.
    sql(db, "INSERT INTO events (mono_s, wall_s, clock_synced, kind, detail_json)"
            " SELECT value, 1.7e9, 0, 'x', hex(randomblob(500)) FROM"
            " (WITH RECURSIVE n(value) AS (SELECT 1 UNION ALL SELECT value + 1 FROM n"
            " WHERE value < 8000) SELECT value FROM n)")  # fmt: skip
    size = db.stat().st_size
    read, _ = io_counts()
    journaldata.surveys(db)
    first, _ = io_counts()
    assert first - read >= size  # the check read the file
    journaldata.surveys(db)
    second, _ = io_counts()
    assert second - first < size // 4  # the same file: not checked again
    sql(db, "UPDATE sessions SET software = 'changed'")
    journaldata.surveys(db)
    third, _ = io_counts()
    assert third - second >= size  # the file changed: checked again


def test_at_most_two_salvaged_copies_are_kept(tmp_path: Path) -> None:
    from cc_daemon.store.salvaged import Salvaged

    cache = Salvaged()
    try:
        for n in range(4):
            db = tmp_path / f"survey{n}.db"
            survey_journal(db, casts=3)
            DAMAGE["garbled-page"](db)
            with pytest.raises(StoreError, match="is damaged"), JournalReader(db, cache=cache) as r:
                r.casts()
            assert cache.salvages_run == n + 1
            assert cache.directory is not None
            kept = sorted(p.name for p in cache.directory.iterdir())
            assert kept == [f"{i + 1}-survey{i}.db" for i in range(max(0, n - 1), n + 1)]
        assert cache.room() <= 2 * db.stat().st_size * 2
    finally:
        cache.close()
    assert cache.directory is None


_READ_AND_WAIT = """
import sys, time
from pathlib import Path
from cc_daemon.store import JournalReader, StoreError
try:
    with JournalReader(Path(sys.argv[1])) as reader:
        reader.casts()
except StoreError:
    pass
print("read", flush=True)
if sys.argv[2] == "wait":
    time.sleep(600)
"""


def leftovers(where: Path) -> list[str]:
    return sorted(p.name for p in where.iterdir() if p.name.startswith("cc-daemon-"))


def test_nothing_is_left_in_the_temporary_directory_when_a_reader_ends(
    damaged: Path, tmp_path: Path
) -> None:
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    env = {**os.environ, "TMPDIR": str(scratch)}
    done = subprocess.run(
        [sys.executable, "-c", _READ_AND_WAIT, str(damaged), "exit"],
        env=env, cwd=REPO, capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    assert done.stdout == "read\n"
    assert leftovers(scratch) == []


def test_what_a_killed_reader_left_is_swept_by_the_next(damaged: Path, tmp_path: Path) -> None:
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    env = {**os.environ, "TMPDIR": str(scratch)}
    with subprocess.Popen(
        [sys.executable, "-c", _READ_AND_WAIT, str(damaged), "wait"],
        env=env, cwd=REPO, stdout=subprocess.PIPE, text=True,
    ) as reader:  # fmt: skip
        try:
            assert reader.stdout is not None
            assert reader.stdout.readline() == "read\n"
        finally:
            reader.send_signal(signal.SIGKILL)
            reader.wait(timeout=30)
            reader.stdout.close() if reader.stdout else None
    left = leftovers(scratch)
    assert left, "the killed reader left its salvaged copy"
    assert all(name.startswith(f"cc-daemon-salvage-{reader.pid}-") for name in left)
    sound = tmp_path / "sound.db"
    survey_journal(sound, casts=1)
    answer = run_command("casts", "--db", str(sound), env={"TMPDIR": str(scratch)})
    assert answer.code == 0
    assert leftovers(scratch) == []  # swept by the next reader
    keep = scratch / f"cc-daemon-salvage-{os.getpid()}-0-mine"  # a live process's: kept
    keep.mkdir()
    run_command("casts", "--db", str(sound), env={"TMPDIR": str(scratch)})
    assert leftovers(scratch) == [keep.name]
    shutil.rmtree(keep)
