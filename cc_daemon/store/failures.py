"""What a storage error means, and how the journal reports trouble without raising.

This module owns the journal's judgement of errors (a bad row, a full disk, a
file that can never be used, a storage problem worth retrying), its logging
that never raises and never floods (`emit`, `RateLimitedLog`), and the naming
of the fresh and spill files it may create. It does no SQLite work itself.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import structlog

from cc_daemon.store import schema

log = structlog.get_logger("cc_daemon.store")

# SQLite's primary result codes (the low byte of an extended code).
SQLITE_CORRUPT = 11
SQLITE_FULL = 13
SQLITE_NOTADB = 26

# A problem with one row (a value SQLite cannot bind, a constraint): retrying
# the same row can never succeed, so such rows are set aside one by one.
# Everything else (OperationalError: full, read-only, locked, I/O; a corrupt
# file; OSError) is about the storage: worth retrying, or (see `is_permanent`)
# a reason to leave the file for a fresh one.
ROW_ERRORS = (
    sqlite3.IntegrityError,
    sqlite3.InterfaceError,
    sqlite3.ProgrammingError,
    sqlite3.DataError,
    OverflowError,
    TypeError,
    ValueError,
)
STORAGE_ERRORS = (sqlite3.Error, OSError, schema.StoreError)


def emit(level: str, event: str, **fields: Any) -> None:
    """Log, and never raise: a log stream that fails (EPIPE, EIO, ENOSPC: the log on
    the same full disk, journald gone) must not stop the journal or reach the daemon."""
    with contextlib.suppress(Exception):
        getattr(log, level)(event, **fields)


class RateLimitedLog:
    """Error logging that says a repeated error once per interval, with a count.

    Repeats are never silenced: the next message carries how many were held
    back. Used from the loop thread and the writer thread, hence the lock.
    Never raises (see `emit`).
    """

    def __init__(self, interval_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self._interval_s = interval_s
        self._clock = clock
        self._lock = threading.Lock()
        self._last: dict[str, tuple[float, int]] = {}

    def error(self, key: str, event: str, **fields: Any) -> None:
        with contextlib.suppress(Exception):
            now = self._clock()
            with self._lock:
                last, held = self._last.get(key, (-float("inf"), 0))
                if now - last < self._interval_s:
                    self._last[key] = (last, held + 1)
                    return
                self._last[key] = (now, 0)
            if held:
                fields["repeated"] = held
            emit("error", event, **fields)


def error_code(exc: BaseException) -> int | None:
    code = getattr(exc, "sqlite_errorcode", None)
    return code & 0xFF if isinstance(code, int) else None


def is_full(exc: BaseException) -> bool:
    return isinstance(exc, sqlite3.Error) and error_code(exc) == SQLITE_FULL


def is_permanent(exc: BaseException) -> bool:
    """Whether `exc` says the file can never be used, however long we wait."""
    if isinstance(exc, schema.IncompatibleFileError):
        return True
    if not isinstance(exc, sqlite3.DatabaseError) or isinstance(exc, ROW_ERRORS):
        return False
    code = error_code(exc)
    if code is not None:
        return code in (SQLITE_CORRUPT, SQLITE_NOTADB)
    text = str(exc)
    return "malformed" in text or "not a database" in text


# Trees that hold devices and kernel files: no journal file or spill file, ever.
SYSTEM_TREES = (Path("/dev"), Path("/proc"), Path("/sys"))


def state_directories() -> list[Path]:
    """The service's state directory, if systemd gave one (`StateDirectory=`)."""
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return [Path(state)] if state else []


def data_directories(candidates: list[Path]) -> list[Path]:
    """`candidates` in order, without repeats and without any under `SYSTEM_TREES`
    (a journal configured as /dev/null must not leave its spill file in /dev)."""
    kept: list[Path] = []
    for directory in candidates:
        try:
            real = Path(os.path.realpath(directory))
        except (OSError, ValueError):
            continue
        system = any(real == tree or tree in real.parents for tree in SYSTEM_TREES)
        if not system and real not in kept:
            kept.append(real)
    return kept


def utc_stamp(wall_s: float) -> str:
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(wall_s))


def unused_path(path: Path) -> Path:
    """`path`, or `path` with `-1`, `-2`, ... before its suffix if that is taken."""
    candidate, n = path, 0
    try:
        while candidate.exists() or Path(f"{candidate}-wal").exists():
            n += 1
            candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
    except OSError:  # a directory we may not look into: trying it will say more
        pass
    return candidate


def free_bytes(directory: Path) -> int | None:
    """Free space on `directory`'s filesystem for us, if it can be told."""
    try:
        stat = os.statvfs(directory)
    except OSError:
        return None
    if stat.f_blocks == 0:  # a filesystem that keeps no count (some FUSE ones)
        return None
    return stat.f_bavail * stat.f_frsize


def write_new_file(text: str, candidates: list[Path]) -> Path | None:
    """Write `text` durably to a new file: the first candidate (made unique) that
    works; None if none does. A file is never left holding part of `text`."""
    for candidate in candidates:
        target = unused_path(candidate)
        created = False
        try:
            with target.open("x", encoding="utf-8") as out:
                created = True
                out.write(text)
                out.flush()
                os.fsync(out.fileno())
        except OSError:
            if created:
                with contextlib.suppress(OSError):
                    target.unlink()  # a part of them is worse than all of them elsewhere
            continue
        return target
    return None
