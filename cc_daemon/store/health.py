"""What the journal says about itself: `JournalHealth`, for status and logs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True, slots=True)
class JournalHealth:
    """A snapshot of the journal's state, for the daemon's status and logs."""

    path: Path  # the file in use: a fresh one if the configured one could never be used
    writable: bool  # the file is open and the last write succeeded
    pending_rows: int  # recorded but not yet committed
    rows_written: int
    write_errors: int  # failed attempts to open or write the file
    dropped_rows: int  # given up for good: buffer overflow or a row SQLite refused
    last_error: str | None
    writer_alive: bool = False  # the writer thread is running (restarted if it ever stops)
    spilled_rows: int = 0  # of pending_rows, those in spill files (awaiting replay)
    spill_files: tuple[Path, ...] = ()
