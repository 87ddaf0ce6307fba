"""`cc-daemon snapshot DEST`: a consistent copy of the journal, even while it is written.

This module owns copying a journal into one self-contained file to carry off
the boat: SQLite's online backup of one read snapshot (`JournalReader`, which
opens the journal read-only and never disturbs the daemon writing it), checked
with `PRAGMA quick_check`, switched out of write-ahead logging so the copy is
a single file, synced to disk when the copy commits, and described (casts,
samples, fixes, events, time span: counted through the reader's bounds, so a
table that is a view in a stranger's file is never run). It never overwrites a
file: DEST is created exclusively (and refused if a `-journal` or `-wal` beside
it, even a dangling symlink, is there), and removed again if the copy fails.
"""

from __future__ import annotations

import errno
import os
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path

from cc_daemon.store import files, guard
from cc_daemon.store.reader import DamagedJournalError, JournalReader, iso_utc
from cc_daemon.store.schema import StoreError
from cc_daemon.store.values import dated

_TIMES = (("fixes", "wall_s"), ("samples", "wall_s"), ("events", "wall_s"))
_SPAN_SQL = (
    "SELECT min(t), max(t) FROM ("
    + " UNION ALL ".join(
        f"SELECT min({dated(c)}) AS t FROM {table} UNION ALL SELECT max({dated(c)}) FROM {table}"
        for table, c in _TIMES
    )
    + f" UNION ALL SELECT min({dated('start_wall_s')}) FROM casts"
    + f" UNION ALL SELECT max({dated('end_wall_s')}) FROM casts)"
)


@dataclass(frozen=True, slots=True)
class SnapshotReport:
    source: Path
    path: Path
    casts: int
    samples: int
    fixes: int
    events: int
    first_wall_s: float | None
    last_wall_s: float | None
    size_bytes: int

    def describe(self) -> str:
        span = (
            "no records"
            if self.first_wall_s is None or self.last_wall_s is None
            else f"{iso_utc(self.first_wall_s)} to {iso_utc(self.last_wall_s)}"
        )
        return (
            f"copied {self.source} to {self.path}: {_count(self.casts, 'cast')}, "
            f"{_count(self.samples, 'sample')}, {_count(self.fixes, 'fix')}, "
            f"{_count(self.events, 'event')}; {span}; {_size(self.size_bytes)}"
        )


def _size(size_bytes: int) -> str:
    if size_bytes < 1_000_000:
        return f"{size_bytes / 1000:.0f} kB"
    return f"{size_bytes / 1e6:.1f} MB"


def _count(n: int, noun: str) -> str:
    plural = "fixes" if noun == "fix" else f"{noun}s"
    return f"{n} {noun if n == 1 else plural}"


def destination(source: Path, dest: Path, *, now: float | None = None) -> Path:
    """DEST itself, or a new name inside it when DEST is a directory."""
    if dest.is_dir():
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(time.time() if now is None else now))
        return dest / f"{source.stem}-snapshot-{stamp}.db"
    return dest


def take_snapshot(source: Path, dest: Path) -> SnapshotReport:
    """Copy journal `source` to `dest` (or into the directory `dest`) consistently.

    Raises `FileExistsError` if the file exists (nothing is touched),
    `StoreError` if the journal cannot be read or the copy is not sound.
    """
    path = destination(source, dest)
    for companion in files.COMPANIONS:  # SQLite would follow a symlink there and write at it
        if os.path.lexists(f"{path}{companion}"):
            raise FileExistsError(errno.EEXIST, "exists", f"{path}{companion}")
    report: SnapshotReport | None = None
    try:
        with JournalReader(source) as reader:  # raises StoreError for a missing journal
            # O_EXCL: never overwrite, even a file that appears while we look.
            os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
            try:
                report = _copy(reader, source, path)
            except BaseException:
                path.unlink(missing_ok=True)
                Path(f"{path}-journal").unlink(missing_ok=True)
                raise
    except DamagedJournalError as exc:
        if report is None:
            raise
        # A copy of what could be read is worth keeping; but it is no backup of all.
        raise DamagedJournalError(
            f"copied only what could be read to {path} ({_counts(report)}): {exc}"
        ) from exc
    return report


def _counts(report: SnapshotReport) -> str:
    return f"{report.casts} casts, {report.samples} samples, {report.fixes} fixes"


_COUNTED = ("casts", "samples", "fixes", "events")


def _rows_in(reader: JournalReader, table: str) -> int:
    """Rows of `table` as the reader reads it (a table that is not one reads as empty)."""
    return int(reader.rows(f"SELECT count(*) FROM {table}", table)[0][0])


def _copy(reader: JournalReader, source: Path, path: Path) -> SnapshotReport:
    target = sqlite3.connect(path, isolation_level=None)
    try:
        bounds = guard.Bounds(target)
        try:
            reader.copy_to(target)
            # One file to carry: the copy inherited the journal's WAL mode.
            target.execute("PRAGMA journal_mode = DELETE").fetchone()
            check = bounds.rows("PRAGMA quick_check")[0][0]
        except (sqlite3.Error, guard.QueryTimeout) as exc:
            raise StoreError(f"could not copy {source} to {path}: {exc}") from exc
        if check != "ok":
            raise StoreError(f"the copy of {source} failed its check: {check}")
    finally:
        target.close()
    # Counted through the reader's bounds: the copy holds whatever the file held.
    casts, samples, fixes, events = (_rows_in(reader, table) for table in _COUNTED)
    first, last = reader.rows(_SPAN_SQL, "the times")[0]
    return SnapshotReport(
        source, path, casts, samples, fixes, events, first, last, path.stat().st_size
    )
