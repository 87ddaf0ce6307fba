"""A journal's files from someone else: what sits where its log, its `-shm` or its
`-journal` belongs (issue 27).

Real files made hostile: the `-wal` a symlink to `/dev/zero` or `/dev/urandom`, a
real FIFO, a sparse 3 GiB file; a FIFO `-shm` or `-journal` beside a journal with a
log. Every reader (the data commands, `snapshot`, `recover`) answers within
seconds and in bounded memory (a child process capped at 1.5 GiB), with the
journal's rows it can read and one line saying which file it did not read; it
never opens a FIFO or a device for reading.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.hostilekit import run_commands
from tests.journalkit import survey_journal


@pytest.fixture(scope="module")
def source(tmp_path_factory: pytest.TempPathFactory) -> Path:
    db = tmp_path_factory.mktemp("source") / "survey.db"
    survey_journal(db, casts=3)
    return db


def sparse(path: Path, size: int) -> None:
    with path.open("wb") as f:
        f.truncate(size)


WALS: dict[str, tuple[Callable[[Path], None], str]] = {
    "dev-zero": (lambda wal: os.symlink("/dev/zero", wal), "is a character device, not a file"),
    "dev-urandom": (
        lambda wal: os.symlink("/dev/urandom", wal),
        "is a character device, not a file",
    ),
    "fifo": (os.mkfifo, "is a FIFO, not a file"),
    "symlink-to-fifo": (
        lambda wal: (os.mkfifo(f"{wal}.fifo"), os.symlink(f"{wal}.fifo", wal)),
        "is a FIFO, not a file",
    ),
    "sparse-3-gib": (lambda wal: sparse(wal, 3 << 30), "is 3.0 GiB, over the 64 MiB"),
}


@pytest.mark.parametrize("form", sorted(WALS))
def test_a_log_that_is_no_file_or_too_big_is_not_read_and_said_in_one_line(
    form: str, source: Path, tmp_path: Path
) -> None:
    db = tmp_path / "survey.db"
    shutil.copyfile(source, db)
    make, said = WALS[form]
    make(Path(f"{db}-wal"))
    sound = run_commands(["export", "--db", str(source), "--format", "csv"])[0]
    samples, events, snapshot, recover = run_commands(
        ["export", "--db", str(db), "--format", "csv"],
        ["export", "--db", str(db), "--format", "csv", "--what", "events"],
        ["snapshot", str(tmp_path / "copy.db"), "--db", str(db)],
        ["recover", "--db", str(db), "-o", str(tmp_path / "new.db")],
    )
    for answer in (samples, events, snapshot):
        line = answer.one_clear_line()
        assert f"the write-ahead log survey.db-wal {said}" in line
    assert samples.stdout == sound.stdout  # every row of the file itself, as on the sound copy
    assert events.stdout.count("\n") == 3  # the header and the file's two events
    assert "copied only what could be read" in snapshot.said[0]
    assert recover.code == 1
    assert f"survey.db-wal {said}" in recover.said[0]
    assert "casts                   3 rows  of 3" in recover.stdout


@pytest.mark.parametrize("companion", ["-shm", "-journal"])
def test_a_fifo_where_sqlite_looks_beside_a_live_journal_is_never_opened(
    companion: str, tmp_path: Path
) -> None:
    # A journal the daemon was killed over: its rows in the -wal, a -shm beside it.
    db = tmp_path / "survey.db"
    survey_journal(db, casts=3, keep_wal=True)
    export = ["export", "--db", str(db), "--format", "csv"]
    sound = run_commands(export)[0]
    assert sound.code == 0 and sound.stdout.count("\n") > 80
    Path(f"{db}-shm").unlink(missing_ok=True)
    os.mkfifo(f"{db}{companion}")
    (samples,) = run_commands(export)
    line = samples.one_clear_line()
    assert f"survey.db{companion} is a FIFO: not opened" in line
    assert samples.stdout == sound.stdout  # the log read from a private copy: nothing lost
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("survey")) == sorted(
        ["survey.db", "survey.db-wal", f"survey.db{companion}"]
    )


@pytest.mark.parametrize(
    ("make", "said"),
    [
        (os.mkfifo, "is a FIFO, not a journal file"),
        (lambda db: os.symlink("/dev/zero", db), "is a character device, not a journal file"),
        (os.mkdir, "is a directory, not a journal file"),
    ],
    ids=["fifo", "dev-zero", "directory"],
)
def test_a_journal_that_is_no_file_is_never_opened(
    make: Callable[[Path], None], said: str, tmp_path: Path
) -> None:
    db = tmp_path / "survey.db"
    make(db)
    answers = run_commands(
        ["casts", "--db", str(db)],
        ["snapshot", str(tmp_path / "copy.db"), "--db", str(db)],
        ["recover", "--db", str(db), "-o", str(tmp_path / "new.db")],
    )
    for answer in answers:
        assert f"survey.db {said}" in answer.one_clear_line()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["survey.db"]
