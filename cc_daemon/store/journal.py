"""The survey journal's write side: fixes, casts, samples and events into SQLite.

This module owns getting rows from the daemon into the journal file and
keeping them safe until they are there. The daemon calls `Journal` from its
asyncio loop; every `record_*`, `start_cast` and `end_cast` stamps the row
(monotonic time, wall-clock UTC, whether the clock looked synchronised) and
appends it to an in-memory list under a lock, in about a microsecond. One
writer thread with its own `sqlite3` connection drains those lists into the file.

It must never block the event loop, never raise into the daemon because
storage (or logging) failed (disk full, read-only, locked, missing, corrupt;
a log stream that is gone), and never drop a cast sample while a telemetry
fix or an event could be dropped instead.

Durability. Rows that belong to a cast (start, samples, end) and events wake
the writer at once and are committed with `synchronous=FULL`, so they are on
disk within milliseconds and survive `kill -9` and a power cut. Telemetry is
committed at least every `FLUSH_INTERVAL_S` with `synchronous=NORMAL`: in WAL
mode a NORMAL commit is in the WAL file (so it survives the process being
killed) but the WAL is not fsynced, so a power cut could lose it. The WAL is
append-only, so the next FULL commit's fsync makes every earlier frame durable
too; the writer forces a FULL commit at least every `FULL_SYNC_INTERVAL_S`,
which bounds telemetry lost to a power cut to that interval plus the flush
interval (6 s; the issue allows 10) while sparing the SD card four fsyncs out
of five between casts.

Transactions hold at most `MAX_TRANSACTION_ROWS` rows, cast rows and events
before telemetry, so a backlog never has to fit on the disk all at once: on a
nearly full disk what fits is committed (cast rows that do not fit are retried
in halves) and only the rest waits. Below `LOW_SPACE_BYTES` free the WAL is
checkpointed and truncated after every transaction, and below
`FIX_RESERVE_BYTES` telemetry waits in memory, so the last of the disk is kept
for casts.

When writing fails, the rows stay in memory (at most `max_buffered_rows` in
all, counting the rows being written; beyond that the oldest fixes go first,
then events, then samples; cast start and end rows are never dropped), the
error is logged at most every `LOG_INTERVAL_S` with a count of repeats, and
the writer reconnects and retries every `RETRY_INTERVAL_S`. A file that can
never be used (corrupt, not a database, another program's, a newer
cc-daemon's) is left untouched and the journal goes on in a fresh file beside
it (`<name>-<UTC stamp>.db`, or in the temporary directory if that fails);
`health().path` says which file is in use. Rows still unwritten when the
journal closes are saved as JSON lines (`<name>-unwritten-<UTC stamp>.jsonl`
beside the journal, else in the temporary directory) rather than lost.
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import structlog

from cc_daemon import __version__
from cc_daemon.protocol import StartMeasuring, Telemetry
from cc_daemon.store import schema

log = structlog.get_logger("cc_daemon.store")

PHASES = frozenset({"soaking", "descending", "dwelling", "ascending", "aborting", "stranded"})
OUTCOMES = frozenset({"completed", "skipped-shallow", "aborted", "unfinished"})
TIMESYNC_FLAG = Path("/run/systemd/timesync/synchronized")
BOOT_ID = Path("/proc/sys/kernel/random/boot_id")

FLUSH_INTERVAL_S = 1.0
FULL_SYNC_INTERVAL_S = 5.0
RETRY_INTERVAL_S = 1.0
# The writer is a thread, so waiting on a lock blocks nobody else; half a
# second rides out a reader's checkpoint without piling up retries.
BUSY_TIMEOUT_S = 0.5
LOG_INTERVAL_S = 30.0
SYNC_CHECK_INTERVAL_S = 1.0
# Rows per transaction: enough to write a backlog fast, few enough that a
# transaction needs little free space (tens of kB) and holds the lock briefly.
MAX_TRANSACTION_ROWS = 500
# Below this much free space the WAL is checkpointed and truncated after every
# transaction (it normally grows to some 4 MB first): a WAL that has taken the
# last free bytes cannot even be checkpointed, since that grows the file.
LOW_SPACE_BYTES = 8 << 20
# Telemetry is not written while less than this is free on the journal's
# filesystem: the last of the disk is kept for casts (fixes wait in memory).
FIX_RESERVE_BYTES = 256 << 10
UNFINISHED_REASON = "no end recorded: the daemon stopped during the cast (crash, kill or power cut)"

# SQLite's primary result codes (the low byte of an extended code).
_SQLITE_CORRUPT = 11
_SQLITE_FULL = 13
_SQLITE_NOTADB = 26

# Row kinds. A row is a tuple: the kind, then its values in the order of the
# matching INSERT (tuples are the cheapest thing to build on the loop thread).
# An event row ends with the `cast_id` of its details (or None), after the
# INSERT's values, so a cast stored under a new id can be followed.
_FIX = 0
_CAST = 1
_SAMPLE = 2
_END = 3
_EVENT = 4
# Which rows to sacrifice first when the buffer is full: fixes (a list of
# their own), then these from the other list; casts never.
_SHED_ORDER = (_EVENT, _SAMPLE)

Row = tuple[Any, ...]

_INSERT_FIX = (
    "INSERT INTO fixes (session_id, mono_s, wall_s, clock_synced, frame, ap_timestamp_s,"
    " lon_e7, lat_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct, measuring_mode,"
    " ap_time_s, ap_time_order) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)"
)
_INSERT_CAST = (
    "INSERT INTO casts (id, session_id, start_mono_s, start_wall_s, start_clock_synced,"
    " ap_timestamp_s, lon_e7, lat_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct,"
    " planned_depth_m, mode, plan_json) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)"
)
_INSERT_SAMPLE = (
    "INSERT INTO samples (cast_id, mono_s, wall_s, clock_synced, depth_m, phase)"
    " VALUES (?, ?, ?, ?, ?, ?)"
)
_UPDATE_END = (
    "UPDATE casts SET end_mono_s = ?, end_wall_s = ?, end_clock_synced = ?, outcome = ?,"
    " reached_depth_m = ?, reason = ? WHERE id = ?"
)
_INSERT_EVENT = (
    "INSERT INTO events (session_id, mono_s, wall_s, clock_synced, kind, detail_json)"
    " VALUES (?, ?, ?, ?, ?, ?)"
)
_RECOVER_UNFINISHED = """
UPDATE casts SET
    outcome = 'unfinished',
    reason = ?,
    reached_depth_m = (SELECT max(depth_m) FROM samples WHERE cast_id = casts.id),
    end_mono_s = (SELECT max(mono_s) FROM samples WHERE cast_id = casts.id),
    end_wall_s = (SELECT wall_s FROM samples WHERE cast_id = casts.id
                  ORDER BY mono_s DESC LIMIT 1),
    end_clock_synced = (SELECT clock_synced FROM samples WHERE cast_id = casts.id
                        ORDER BY mono_s DESC LIMIT 1)
WHERE outcome IS NULL
"""

# The spill file's columns per row kind: a row's values after its kind, in order.
_SPILL_LAYOUT: dict[int, tuple[str, tuple[str, ...]]] = {
    _FIX: (
        "fixes",
        (
            "mono_s",
            "wall_s",
            "clock_synced",
            "frame",
            "ap_timestamp_s",
            "lon_e7",
            "lat_e7",
            "alt_mm",
            "sonar_distance_mm",
            "sonar_confidence_pct",
            "measuring_mode",
            "ap_time_s",
            "ap_time_order",
        ),
    ),
    _CAST: (
        "casts",
        (
            "id",
            "start_mono_s",
            "start_wall_s",
            "start_clock_synced",
            "ap_timestamp_s",
            "lon_e7",
            "lat_e7",
            "alt_mm",
            "sonar_distance_mm",
            "sonar_confidence_pct",
            "planned_depth_m",
            "mode",
            "plan_json",
        ),
    ),
    _SAMPLE: ("samples", ("cast_id", "mono_s", "wall_s", "clock_synced", "depth_m", "phase")),
    _END: (
        "cast_ends",
        (
            "cast_id",
            "end_mono_s",
            "end_wall_s",
            "end_clock_synced",
            "outcome",
            "reached_depth_m",
            "reason",
        ),
    ),
    _EVENT: ("events", ("mono_s", "wall_s", "clock_synced", "kind", "detail_json")),
}

# A problem with one row (a value SQLite cannot bind, a constraint): retrying
# the same row can never succeed, so such rows are set aside one by one.
# Everything else (OperationalError: full, read-only, locked, I/O; a corrupt
# file; OSError) is about the storage: worth retrying, or (see `_is_permanent`)
# a reason to leave the file for a fresh one.
_ROW_ERRORS = (
    sqlite3.IntegrityError,
    sqlite3.InterfaceError,
    sqlite3.ProgrammingError,
    sqlite3.DataError,
    OverflowError,
    TypeError,
    ValueError,
)
_STORAGE_ERRORS = (sqlite3.Error, OSError, schema.StoreError)


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


def default_store_path() -> Path:
    """`$STATE_DIRECTORY/cc-daemon.db` under systemd, else `./cc-daemon.db`."""
    # systemd joins several StateDirectory= entries with ':'; the first is ours.
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return Path(state) / "cc-daemon.db" if state else Path("cc-daemon.db")


def _emit(level: str, event: str, **fields: Any) -> None:
    """Log, and never raise: a log stream that fails (EPIPE, EIO, ENOSPC: the log on
    the same full disk, journald gone) must not stop the journal or reach the daemon."""
    with contextlib.suppress(Exception):
        getattr(log, level)(event, **fields)


class _RateLimitedLog:
    """Error logging that says a repeated error once per interval, with a count.

    Repeats are never silenced: the next message carries how many were held
    back. Used from the loop thread and the writer thread, hence the lock.
    Never raises (see `_emit`).
    """

    def __init__(self, interval_s: float) -> None:
        self._interval_s = interval_s
        self._lock = threading.Lock()
        self._last: dict[str, tuple[float, int]] = {}

    def error(self, key: str, event: str, **fields: Any) -> None:
        with contextlib.suppress(Exception):
            now = time.monotonic()
            with self._lock:
                last, held = self._last.get(key, (-float("inf"), 0))
                if now - last < self._interval_s:
                    self._last[key] = (last, held + 1)
                    return
                self._last[key] = (now, 0)
            if held:
                fields["repeated"] = held
            _emit("error", event, **fields)


def _shed(rows: list[Row], excess: int) -> tuple[list[Row], int]:
    """Drop `excess` rows, oldest first in `_SHED_ORDER`; return what is kept and how many went."""
    dropped = 0
    for kind in _SHED_ORDER:
        if dropped >= excess:
            break
        kept: list[Row] = []
        for row in rows:
            if dropped < excess and row[0] == kind:
                dropped += 1
            else:
                kept.append(row)
        rows = kept
    return rows, dropped


def _to_json(value: object) -> str:
    # default=str: a plan or event detail holding a Path, an enum or a
    # datetime is stored readably instead of failing the whole row.
    return json.dumps(value, default=str, sort_keys=True, separators=(",", ":"))


def _boot_id() -> str | None:
    try:
        return BOOT_ID.read_text().strip()
    except OSError:
        return None


def _error_code(exc: BaseException) -> int | None:
    code = getattr(exc, "sqlite_errorcode", None)
    return code & 0xFF if isinstance(code, int) else None


def _is_full(exc: BaseException) -> bool:
    return isinstance(exc, sqlite3.Error) and _error_code(exc) == _SQLITE_FULL


def _is_permanent(exc: BaseException) -> bool:
    """Whether `exc` says the file can never be used, however long we wait."""
    if isinstance(exc, schema.IncompatibleFileError):
        return True
    if not isinstance(exc, sqlite3.DatabaseError) or isinstance(exc, _ROW_ERRORS):
        return False
    code = _error_code(exc)
    if code is not None:
        return code in (_SQLITE_CORRUPT, _SQLITE_NOTADB)
    text = str(exc)
    return "malformed" in text or "not a database" in text


def _utc_stamp(wall_s: float) -> str:
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(wall_s))


def _unused(path: Path) -> Path:
    """`path`, or `path` with `-1`, `-2`, ... before its suffix if that is taken."""
    candidate, n = path, 0
    try:
        while candidate.exists() or Path(f"{candidate}-wal").exists():
            n += 1
            candidate = path.with_name(f"{path.stem}-{n}{path.suffix}")
    except OSError:  # a directory we may not look into: trying it will say more
        pass
    return candidate


class Journal:
    """The survey journal. Construct, `open()`, record from the loop, `close()`.

    Call `open()` and `close()` from the thread that owns the daemon's start and
    stop (they are synchronous; `open` may migrate a large file). All the other
    methods are for the asyncio loop thread and return in microseconds.
    """

    def __init__(
        self,
        path: Path,
        *,
        monotonic: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        timesync_flag: Path = TIMESYNC_FLAG,
        max_buffered_rows: int = 100_000,
        on_connect: Callable[[sqlite3.Connection], None] | None = None,
    ) -> None:
        """`on_connect` is called with every new connection before use (tests use it
        to set `PRAGMA max_page_count`, which makes SQLite report a full disk)."""
        if max_buffered_rows < 1:
            raise ValueError(f"max_buffered_rows={max_buffered_rows!r}: allowed >= 1")
        self.path = Path(path)  # the configured file; health().path is the one in use
        self._monotonic = monotonic
        self._wall = wall
        self._timesync_flag = str(timesync_flag)
        self._max_rows = max_buffered_rows
        self._on_connect = on_connect

        # Shared between the loop thread and the writer: guarded by _lock. The
        # rows not yet written are in `_urgent` (cast rows and events), `_fixes`
        # and `_in_flight` (taken by the writer for the transaction it is in).
        self._lock = threading.Lock()
        self._urgent: list[Row] = []
        self._fixes: list[Row] = []
        self._in_flight: list[Row] = []
        self._next_cast_id = 1
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._writer_running = False  # set before the thread starts, cleared as it ends
        self._writer_lock = threading.Lock()
        self._writer_restarted_at = -float("inf")
        self._closed = False

        # Loop-thread only.
        self._sync_checked_at = -float("inf")
        self._synced = 0
        self._open_casts: set[int] = set()

        # Writer only (open() uses them before the writer starts). The
        # counters are read by health() from the loop: int reads are atomic.
        self._conn: sqlite3.Connection | None = None
        self._active = self.path  # the file written to
        self._replacements: list[Path] | None = None  # set once _active proved unusable
        self._session_id: int | None = None
        self._recovered = False
        self._id_map: dict[int, int] = {}
        # Start rows of casts committed but not yet ended, by the id they were
        # recorded with: written again if the run moves to a fresh file.
        self._unended: dict[int, Row] = {}
        self._failing = False
        self._sync_mode = ""
        self._last_full_sync = -float("inf")
        self._rows_written = 0
        self._write_errors = 0
        self._dropped_rows = 0
        self._last_error: str | None = None
        self._errors = _RateLimitedLog(LOG_INTERVAL_S)

    # ----------------------------------------------------------- lifecycle

    def open(self) -> list[int]:
        """Open (create, migrate) the file, close crashed casts, start the writer.

        Returns the ids of casts found without an end and marked `unfinished`.
        Never raises because the file is unusable: it logs the error, and the
        writer keeps the rows in memory and retries every second (casts found
        unfinished then are marked and logged when the file first opens). A file
        that can never be used is left as it is and a fresh one started (logged
        at critical).
        """
        if self._thread is not None or self._closed:
            raise RuntimeError("Journal.open() called twice or after close()")
        recovered: list[int] = []
        try:
            recovered = self._open_file()
        except Exception as exc:  # whatever it is, the daemon must start: log, retry later
            self._fail(exc, "journal cannot be opened; keeping rows in memory")
        self._start_writer()
        return recovered

    def close(self, timeout: float = 5.0) -> None:
        """Write what can be written (waiting up to `timeout` s), stop the writer, close.

        Rows that could not be written are saved to a spill file (JSON lines) and
        the count logged at error; never raises.
        """
        if self._closed:
            return
        self._closed = True
        try:
            self._close(timeout)
        except Exception as exc:  # close() runs at shutdown: it must not stop it
            _emit("error", "journal close failed", error=repr(exc), path=str(self._active))

    def _close(self, timeout: float) -> None:
        thread = self._thread
        if thread is not None:
            dead = not thread.is_alive()  # asked before it is told to stop, and does
            self._stop.set()
            self._wake.set()
            if dead:
                # The writer died: a new one makes the last attempt at the file.
                _emit("error", "journal writer had stopped; restarting it to write what is left")
                with contextlib.suppress(Exception):
                    self._start_writer()
                    thread = self._thread
            assert thread is not None
            thread.join(timeout)
            if thread.is_alive():
                with self._lock:
                    rows = [*self._in_flight, *self._urgent, *self._fixes]
                spilled = self._spill(rows) if rows else None
                _emit(
                    "error",
                    "journal writer did not finish in time; unwritten rows saved to a spill"
                    " file (some may reach the journal too)"
                    if spilled
                    else "journal writer did not finish in time; unwritten rows may be lost",
                    timeout_s=timeout,
                    pending_rows=len(rows),
                    spill_file=str(spilled) if spilled else None,
                    path=str(self._active),
                )
                return
        with self._lock:
            rows = [*self._in_flight, *self._urgent, *self._fixes]
            self._in_flight, self._urgent, self._fixes = [], [], []
        if not rows:
            return
        spilled = self._spill(rows)
        _emit(
            "error",
            "journal closed with rows it could not write; saved to a spill file"
            if spilled
            else "journal closed with rows it could not write; they are lost",
            rows=len(rows),
            spill_file=str(spilled) if spilled else None,
            path=str(self._active),
            opened=thread is not None,
            last_error=self._last_error,
        )

    def __enter__(self) -> Journal:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def health(self) -> JournalHealth:
        with self._lock:  # pending and written from the same instant
            pending = len(self._urgent) + len(self._fixes) + len(self._in_flight)
            written = self._rows_written
        thread = self._thread
        return JournalHealth(
            path=self._active,
            writable=self._conn is not None and not self._failing,
            pending_rows=pending,
            rows_written=written,
            write_errors=self._write_errors,
            dropped_rows=self._dropped_rows,
            last_error=self._last_error,
            writer_alive=thread is not None and thread.is_alive(),
        )

    # ------------------------------------------------- loop-thread recording
    # Each method catches every exception: the journal's contract is that it
    # never takes the daemon down, and a bad argument or an injected clock that
    # fails is logged instead of ending a cast. Logging itself never raises.

    def record_fix(
        self,
        msg: Telemetry | StartMeasuring,
        *,
        ap_time_s: int | None = None,
        ap_time_order: str | None = None,
    ) -> None:
        """A telemetry fix (`P-T`) or a start-measuring frame (`P-M`), as received,
        with the autopilot's clock as decoded in byte order `ap_time_order`."""
        try:
            mono = self._monotonic()
            ts, lon, lat, alt, sonar, confidence, *mode = msg  # mode: the 26-byte M's
            self._append(
                (
                    _FIX,
                    mono,
                    self._wall(),
                    self._clock_synced(mono),
                    msg.frame,
                    ts,
                    lon,
                    lat,
                    alt,
                    sonar,
                    confidence,
                    mode[0] if mode else None,
                    ap_time_s,
                    ap_time_order,
                )
            )
        except Exception as exc:
            self._errors.error("record_fix", "journal could not record a fix", error=repr(exc))

    def start_cast(
        self,
        station: StartMeasuring,
        *,
        planned_depth_m: float,
        mode: str,
        plan: dict[str, object],
    ) -> int:
        """Begin a cast at `station`; return its id (allocated here, after the file's last)."""
        with self._lock:
            cast_id = self._next_cast_id
            self._next_cast_id += 1
        self._open_casts.add(cast_id)
        try:
            mono = self._monotonic()
            try:
                plan_json = _to_json(plan)
            except (TypeError, ValueError) as exc:  # a circular plan, say
                plan_json = _to_json({"unserialisable_plan": repr(exc)})
            row = (_CAST, cast_id, mono, self._wall(), self._clock_synced(mono), *station[:6])
            self._append((*row, planned_depth_m, mode, plan_json))
        except Exception as exc:
            self._errors.error("start_cast", "journal could not record a cast", error=repr(exc))
        return cast_id

    def record_sample(self, cast_id: int, depth_m: float, phase: str) -> None:
        """One probe depth of cast `cast_id`, in metres, with the cast's phase."""
        try:
            mono = self._monotonic()
            if phase not in PHASES or cast_id not in self._open_casts:
                self._errors.error(
                    f"sample:{phase}:{cast_id in self._open_casts}",
                    "journal: sample with an unknown phase or for a cast not running;"
                    " stored as given",
                    cast_id=cast_id,
                    phase=phase,
                )
            self._append(
                (_SAMPLE, cast_id, mono, self._wall(), self._clock_synced(mono), depth_m, phase)
            )
        except Exception as exc:
            self._errors.error(
                "record_sample", "journal could not record a sample", error=repr(exc)
            )

    def end_cast(
        self,
        cast_id: int,
        *,
        outcome: str,
        reached_depth_m: float,
        reason: str | None = None,
    ) -> None:
        """Close cast `cast_id` with its outcome and the deepest depth it reached."""
        try:
            mono = self._monotonic()
            if outcome not in OUTCOMES or cast_id not in self._open_casts:
                self._errors.error(
                    f"end:{outcome}:{cast_id in self._open_casts}",
                    "journal: cast end with an unknown outcome or for a cast not running;"
                    " stored as given",
                    cast_id=cast_id,
                    outcome=outcome,
                )
            self._open_casts.discard(cast_id)
            self._append(
                (
                    _END,
                    cast_id,
                    mono,
                    self._wall(),
                    self._clock_synced(mono),
                    outcome,
                    reached_depth_m,
                    reason,
                )
            )
        except Exception as exc:
            self._errors.error("end_cast", "journal could not record a cast end", error=repr(exc))

    def record_event(self, kind: str, **detail: object) -> None:
        """A link or fault event (`port_lost`, `winch_fault`, ...) with its details.

        A `cast_id` in the details follows the cast if it is stored under a new id.
        """
        try:
            mono = self._monotonic()
            ref = detail.get("cast_id")
            row = (
                _EVENT,
                mono,
                self._wall(),
                self._clock_synced(mono),
                kind,
                _to_json(detail),
                ref if type(ref) is int else None,
            )
            self._append(row)
        except Exception as exc:
            self._errors.error("record_event", "journal could not record an event", error=repr(exc))

    def _clock_synced(self, mono: float) -> int:
        # A stat() a second at most: the flag changes once per boot or so.
        if not 0.0 <= mono - self._sync_checked_at < SYNC_CHECK_INTERVAL_S:
            self._sync_checked_at = mono
            self._synced = 1 if os.path.exists(self._timesync_flag) else 0
        return self._synced

    def _append(self, row: Row) -> None:
        if self._closed:
            self._errors.error("closed", "journal is closed; row not recorded", kind=row[0])
            return
        fix = row[0] == _FIX
        with self._lock:
            (self._fixes if fix else self._urgent).append(row)
            total = len(self._urgent) + len(self._fixes) + len(self._in_flight)
            # One bound over everything unwritten. Shed to 90 % so this runs once
            # per many rows, not per row.
            dropped = (
                self._shed_locked(total - self._max_rows * 9 // 10) if total > self._max_rows else 0
            )
        if dropped:
            self._count_dropped(dropped)
        if not fix and not self._wake.is_set():
            self._wake.set()
        if not self._writer_running and self._thread is not None:
            self._restart_writer()

    def _shed_locked(self, excess: int) -> int:
        """Drop `excess` rows not being written: the oldest fixes, then events, then samples."""
        dropped = min(excess, len(self._fixes))
        del self._fixes[:dropped]
        if excess > dropped:
            self._urgent, more = _shed(self._urgent, excess - dropped)
            dropped += more
        return dropped

    def _count_dropped(self, dropped: int) -> None:
        with self._lock:  # both threads drop rows
            self._dropped_rows += dropped
            total = self._dropped_rows
        self._errors.error(
            "dropped",
            "journal buffer full; oldest rows dropped",
            dropped_rows=total,
            max_buffered_rows=self._max_rows,
            path=str(self._active),
        )

    # ------------------------------------------------------------- writer

    def _start_writer(self) -> None:
        thread = threading.Thread(target=self._writer_main, name="cc-daemon-journal", daemon=True)
        self._writer_running = True
        self._thread = thread
        try:
            thread.start()
        except BaseException:
            self._writer_running = False
            raise

    def _restart_writer(self) -> None:
        """Start a new writer if the last one ended (it cannot, short of a bug); from the loop."""
        if self._closed or not self._writer_lock.acquire(blocking=False):
            return
        try:
            now = time.monotonic()
            if self._writer_running or now - self._writer_restarted_at < RETRY_INTERVAL_S:
                return
            self._writer_restarted_at = now
            self._start_writer()
            _emit("error", "journal writer thread had stopped; restarted", path=str(self._active))
        except Exception as exc:
            self._errors.error(
                "restart", "journal writer thread stopped and cannot restart", error=repr(exc)
            )
        finally:
            self._writer_lock.release()

    def _writer_main(self) -> None:
        try:
            self._writer_loop()
        except Exception as exc:  # the loop catches everything; this is belt and braces
            _emit("error", "journal writer stopped by an error", error=repr(exc))
        finally:
            with contextlib.suppress(Exception):
                self._disconnect()
            self._writer_running = False

    def _writer_loop(self) -> None:
        deadline = time.monotonic() + FLUSH_INTERVAL_S
        while True:
            stopping = False
            try:
                stopping = self._stop.is_set()
                if not stopping:
                    if self._failing:
                        # Ignore wake-ups while failing: retry once a second, not per row.
                        self._stop.wait(RETRY_INTERVAL_S)
                    else:
                        self._wake.wait(max(0.0, deadline - time.monotonic()))
                    self._wake.clear()
                    stopping = self._stop.is_set()
                deadline = time.monotonic() + FLUSH_INTERVAL_S
                self._writer_pass()
            except Exception as exc:  # a bug here must not end the thread: rows would pile up
                self._errors.error("writer", "journal writer pass failed", error=repr(exc))
                if not stopping:
                    self._stop.wait(RETRY_INTERVAL_S)  # and must not spin either
            if stopping:
                break

    def _writer_pass(self) -> None:
        was_failing = self._failing
        if self._conn is None:
            try:
                self._open_file()
            except _STORAGE_ERRORS as exc:
                self._fail(exc, "journal cannot be opened; keeping rows in memory")
                return
        written_now = 0
        while True:
            with self._lock:
                chunk = self._take_chunk_locked(urgent=True)
            if not chunk:
                # Cast rows and events are all in; now telemetry, if there is room.
                if not self._fixes or not self._room_for_fixes():
                    break
                with self._lock:
                    chunk = self._take_chunk_locked(urgent=False)
                if not chunk:
                    break
            done = written = 0
            error: BaseException | None = None
            try:
                done, written, error = self._commit(chunk)
            finally:
                # Whatever happened, what was not committed goes back, in order.
                with self._lock:
                    self._rows_written += written
                    dropped = self._put_back_locked(chunk[done:])
                written_now += written
                if dropped:
                    self._count_dropped(dropped)
            if error is not None:
                if _is_permanent(error):
                    self._abandon(error)
                self._fail(error, "journal write failed; keeping rows in memory")
                return
            free = self._free_bytes()
            if free is not None and free < LOW_SPACE_BYTES:
                self._checkpoint()
        self._failing = False
        if was_failing:
            _emit("info", "journal writable again", rows=written_now, path=str(self._active))

    def _take_chunk_locked(self, *, urgent: bool) -> list[Row]:
        """The next transaction's rows: the oldest cast rows and events, or fixes."""
        rows = self._urgent if urgent else self._fixes
        chunk = rows[:MAX_TRANSACTION_ROWS]
        del rows[: len(chunk)]
        self._in_flight = chunk
        return chunk

    def _free_bytes(self) -> int | None:
        """Free space on the journal's filesystem for us, if it can be told."""
        try:
            stat = os.statvfs(self._active.parent)
        except OSError:
            return None
        if stat.f_blocks == 0:  # a filesystem that keeps no count (some FUSE ones)
            return None
        return stat.f_bavail * stat.f_frsize

    def _room_for_fixes(self) -> bool:
        """Whether the filesystem has more than `FIX_RESERVE_BYTES` free (if it can tell)."""
        free = self._free_bytes()
        if free is None or free >= FIX_RESERVE_BYTES:
            return True
        self._last_error = f"disk nearly full: {free} bytes free"
        self._errors.error(
            "reserve",
            "journal disk nearly full; telemetry held in memory to keep the space for casts",
            free_bytes=free,
            reserve_bytes=FIX_RESERVE_BYTES,
            pending_rows=len(self._urgent) + len(self._fixes) + len(self._in_flight),
            path=str(self._active),
        )
        return False

    def _put_back_locked(self, rows: list[Row]) -> int:
        """Return uncommitted rows to the front of their lists; shed if over the bound."""
        self._in_flight = []
        if not rows:
            return 0
        self._urgent[:0] = [row for row in rows if row[0] != _FIX]
        self._fixes[:0] = [row for row in rows if row[0] == _FIX]
        excess = len(self._urgent) + len(self._fixes) - self._max_rows
        return self._shed_locked(excess) if excess > 0 else 0

    def _commit(self, chunk: list[Row]) -> tuple[int, int, BaseException | None]:
        """Commit `chunk` from its front; cast rows on a full disk in smaller transactions.

        Returns how many rows from the front are done with (committed or refused
        by SQLite), how many of them were committed, and the storage error that
        stopped it, if one did.
        """
        size = len(chunk)
        halve = chunk[0][0] != _FIX  # fixes wait for room whole; cast rows take what fits
        checkpointed = False
        done = written = 0
        while done < len(chunk):
            part = chunk[done : done + size]
            try:
                try:
                    written += self._write(part, one_by_one=False)
                except _ROW_ERRORS:
                    written += self._write(part, one_by_one=True)
            except _STORAGE_ERRORS as exc:
                if not _is_full(exc):
                    return done, written, exc
                if not checkpointed:
                    # The WAL only restarts from its beginning after a checkpoint
                    # (by default when it reaches 4 MB): on a nearly full disk,
                    # moving its pages into the file and truncating it frees space.
                    checkpointed = True
                    self._checkpoint()
                    continue
                if not halve or size == 1:
                    return done, written, exc
                size //= 2
                continue
            done += len(part)
        return done, written, None

    def _checkpoint(self) -> None:
        conn = self._conn
        if conn is not None:
            with contextlib.suppress(sqlite3.Error):
                conn.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()

    def _open_file(self) -> list[int]:
        """Connect to the file in use; if it can never be used, to a fresh one instead."""
        if self._replacements is None:
            try:
                return self._connect(self._active)
            except _STORAGE_ERRORS as exc:
                if not _is_permanent(exc):
                    raise
                self._write_errors += 1
                self._last_error = f"{type(exc).__name__}: {exc}"
                self._abandon(exc)
        assert self._replacements is not None
        error: BaseException | None = None
        for candidate in self._replacements:
            try:
                found = self._connect(candidate)
            except _STORAGE_ERRORS as exc:
                error = exc
                continue
            bad, self._active, self._replacements = self._active, candidate, None
            if self._unended:
                # Casts still running when the old file failed: their samples and
                # ends come here, so their start rows (the station) must too.
                with self._lock:
                    self._urgent[:0] = list(self._unended.values())
                self._unended.clear()
            _emit(
                "critical",
                "journal now writing to a new file",
                path=str(candidate),
                instead_of=str(bad),
            )
            return found
        assert error is not None
        raise error

    def _abandon(self, exc: BaseException) -> None:
        """The file in use can never be used: leave it untouched and pick fresh ones."""
        self._disconnect()
        bad = self._active
        try:
            stamp = _utc_stamp(self._wall())
        except Exception:
            stamp = _utc_stamp(time.time())
        name = f"{self.path.stem}-{stamp}{self.path.suffix or '.db'}"
        self._replacements = [_unused(directory / name) for directory in self._fallback_dirs()]
        _emit(
            "critical",
            "journal file cannot be used (corrupt, not a journal, or from a newer cc-daemon);"
            " leaving it untouched and starting a new file",
            path=str(bad),
            error=f"{type(exc).__name__}: {exc}",
            new_path=str(self._replacements[0]),
            pending_rows=len(self._urgent) + len(self._fixes) + len(self._in_flight),
        )

    def _fallback_dirs(self) -> list[Path]:
        """Where a fresh file or a spill file may go: beside the journal, else $TMPDIR."""
        directories: list[Path] = []
        candidates = [self._active.parent, self.path.parent]
        with contextlib.suppress(Exception):  # no usable temporary directory at all
            candidates.append(Path(tempfile.gettempdir()))
        for directory in candidates:
            if directory not in directories:
                directories.append(directory)
        return directories

    def _connect(self, path: Path) -> list[int]:
        """Open the file and make it ready; the first time, close casts a crash left open."""
        conn = sqlite3.connect(
            path,
            timeout=BUSY_TIMEOUT_S,
            isolation_level=None,  # explicit BEGIN/COMMIT: we decide what a transaction holds
            check_same_thread=False,  # open() connects, then hands over to the writer thread
        )
        found: list[tuple[int, int, float | None]] = []
        try:
            if self._on_connect is not None:
                self._on_connect(conn)
            # Refuse another program's file or a newer journal before changing anything.
            schema.file_version(conn)
            mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise schema.StoreError(f"cannot switch the file to WAL (journal_mode={mode})")
            old, new = schema.migrate(conn)
            if old not in (0, new):
                _emit("info", "journal migrated", path=str(path), from_version=old, to_version=new)
            conn.execute("BEGIN IMMEDIATE")
            try:
                self._ensure_session(conn)
                if not self._recovered:
                    found = self._recover(conn)
                max_id = conn.execute("SELECT coalesce(max(id), 0) FROM casts").fetchone()[0]
                conn.execute("COMMIT")
            except BaseException:
                if conn.in_transaction:
                    conn.execute("ROLLBACK")
                raise
        except BaseException:
            conn.close()
            raise
        self._recovered = True
        with self._lock:
            self._next_cast_id = max(self._next_cast_id, int(max_id) + 1)
        self._conn = conn
        self._sync_mode = ""
        self._failing = False
        for cast_id, samples, reached in found:
            _emit(
                "warning",
                "cast left unfinished by a crash; marked unfinished",
                cast_id=cast_id,
                samples=samples,
                reached_depth_m=reached,
                path=str(path),
            )
        return [cast_id for cast_id, _, _ in found]

    def _ensure_session(self, conn: sqlite3.Connection) -> None:
        if (
            self._session_id is not None
            and conn.execute("SELECT 1 FROM sessions WHERE id = ?", (self._session_id,)).fetchone()
        ):
            return
        mono = self._monotonic()
        cursor = conn.execute(
            "INSERT INTO sessions (boot_id, pid, software, opened_mono_s, opened_wall_s,"
            " clock_synced) VALUES (?, ?, ?, ?, ?, ?)",
            (
                _boot_id(),
                os.getpid(),
                f"cc-daemon {__version__}",
                mono,
                self._wall(),
                1 if os.path.exists(self._timesync_flag) else 0,
            ),
        )
        self._session_id = cursor.lastrowid

    def _recover(self, conn: sqlite3.Connection) -> list[tuple[int, int, float | None]]:
        found = conn.execute(
            "SELECT c.id, count(s.id), max(s.depth_m) FROM casts c"
            " LEFT JOIN samples s ON s.cast_id = c.id"
            " WHERE c.outcome IS NULL GROUP BY c.id ORDER BY c.id"
        ).fetchall()
        if found:
            conn.execute(_RECOVER_UNFINISHED, (UNFINISHED_REASON,))
        return [(int(i), int(n), deepest) for i, n, deepest in found]

    def _write(self, rows: list[Row], *, one_by_one: bool) -> int:
        """Commit `rows` in one transaction; one by one, setting aside rows SQLite refuses.

        Returns how many rows were committed.
        """
        conn = self._conn
        assert conn is not None
        now = time.monotonic()
        durable = now - self._last_full_sync >= FULL_SYNC_INTERVAL_S or any(
            row[0] != _FIX for row in rows
        )
        mode = "FULL" if durable else "NORMAL"
        if mode != self._sync_mode:
            conn.execute(f"PRAGMA synchronous = {mode}")
            self._sync_mode = mode
        new_ids: dict[int, int] = {}
        refused: list[tuple[Row, Exception]] = []
        conn.execute("BEGIN IMMEDIATE")
        try:
            for row in rows:
                if not one_by_one:
                    self._insert(conn, row, new_ids)
                    continue
                conn.execute("SAVEPOINT one_row")
                try:
                    self._insert(conn, row, new_ids)
                except _ROW_ERRORS as exc:
                    conn.execute("ROLLBACK TO one_row")
                    refused.append((row, exc))
                conn.execute("RELEASE one_row")
            conn.execute("COMMIT")
        except BaseException:
            if conn.in_transaction:
                with contextlib.suppress(sqlite3.Error):
                    conn.execute("ROLLBACK")
            raise
        self._id_map.update(new_ids)
        if durable:
            self._last_full_sync = now
        if rows[0][0] != _FIX:  # transactions hold fixes only, or none
            set_aside = {id(row) for row, _ in refused}
            for row in rows:
                if row[0] == _CAST and id(row) not in set_aside:
                    self._unended[row[1]] = row
                elif row[0] == _END:
                    self._unended.pop(row[1], None)
        for row, error in refused:
            with self._lock:
                self._dropped_rows += 1
            self._errors.error(
                f"refused:{type(error).__name__}",
                "journal: SQLite refused a row; it is dropped",
                row=repr(row),
                error=repr(error),
            )
        return len(rows) - len(refused)

    def _stored_id(self, cast_id: int, new_ids: dict[int, int]) -> int:
        """The id cast `cast_id` is stored under (another if its own was taken)."""
        return new_ids.get(cast_id) or self._id_map.get(cast_id, cast_id)

    def _event_detail(self, row: Row, new_ids: dict[int, int]) -> str:
        detail_json: str = row[5]
        ref = row[6]
        if ref is None or self._stored_id(ref, new_ids) == ref:
            return detail_json
        detail = json.loads(detail_json)
        detail["cast_id"] = self._stored_id(ref, new_ids)
        return _to_json(detail)

    def _insert(self, conn: sqlite3.Connection, row: Row, new_ids: dict[int, int]) -> None:
        kind = row[0]
        if kind == _FIX:
            conn.execute(_INSERT_FIX, (self._session_id, *row[1:]))
        elif kind == _SAMPLE:
            conn.execute(_INSERT_SAMPLE, (self._stored_id(row[1], new_ids), *row[2:]))
        elif kind == _CAST:
            self._insert_cast(conn, row, new_ids)
        elif kind == _END:
            cursor = conn.execute(_UPDATE_END, (*row[2:], self._stored_id(row[1], new_ids)))
            if cursor.rowcount == 0:
                self._errors.error(
                    "end-unknown",
                    "journal: end of a cast that is not in the file",
                    cast_id=row[1],
                )
        elif kind == _EVENT:
            detail_json = self._event_detail(row, new_ids)
            conn.execute(_INSERT_EVENT, (self._session_id, *row[1:5], detail_json))
        else:
            raise ValueError(f"unknown journal row kind {kind!r}")

    def _insert_cast(self, conn: sqlite3.Connection, row: Row, new_ids: dict[int, int]) -> None:
        cast_id = row[1]
        # A cast written again into a fresh file keeps the id it was stored under.
        wanted = self._id_map.get(cast_id, cast_id)
        taken = conn.execute("SELECT 1 FROM casts WHERE id = ?", (wanted,)).fetchone()
        if not taken:
            conn.execute(_INSERT_CAST, (wanted, self._session_id, *row[2:]))
            return
        # The id was handed out while the file could not be read (so the last
        # id in it was unknown), or another process wrote the same file: store
        # the cast under a fresh id and send its samples, end and events there too.
        cursor = conn.execute(_INSERT_CAST, (None, self._session_id, *row[2:]))
        assert cursor.lastrowid is not None
        new_ids[cast_id] = cursor.lastrowid
        with self._lock:  # ids handed out from now on must not meet this one
            self._next_cast_id = max(self._next_cast_id, cursor.lastrowid + 1)
        _emit(
            "warning",
            "journal: cast id already in the file; stored under a new id",
            cast_id=cast_id,
            stored_as=cursor.lastrowid,
            path=str(self._active),
        )

    def _fail(self, exc: BaseException, event: str) -> None:
        self._write_errors += 1
        self._last_error = f"{type(exc).__name__}: {exc}"
        self._failing = True
        self._disconnect()
        self._errors.error(
            f"fail:{exc}",
            event,
            error=self._last_error,
            pending_rows=len(self._urgent) + len(self._fixes) + len(self._in_flight),
            path=str(self._active),
        )

    def _disconnect(self) -> None:
        # Reconnecting after a failure is what clears a read-only or replaced
        # file: an open connection keeps the mode and inode it started with.
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(sqlite3.Error):
                conn.close()

    # ------------------------------------------------------------- spill

    def _spill(self, rows: list[Row]) -> Path | None:
        """Save rows the journal could not write as JSON lines; return the file, or None."""
        try:
            stamp = _utc_stamp(time.time())
            name = f"{self.path.stem}-unwritten-{stamp}.jsonl"
            directories = self._fallback_dirs()
            lines = "".join(self._spill_line(row) + "\n" for row in rows)
        except Exception as exc:
            _emit("error", "journal could not prepare its spill file", error=repr(exc))
            return None
        for directory in directories:
            target = _unused(directory / name)
            created = False
            try:
                with target.open("x", encoding="utf-8") as out:
                    created = True
                    out.write(lines)
                    out.flush()
                    os.fsync(out.fileno())
            except OSError:
                if created:
                    with contextlib.suppress(OSError):
                        target.unlink()  # a part of them is worse than all of them elsewhere
                continue
            return target
        return None

    def _spill_line(self, row: Row) -> str:
        try:
            table, columns = _SPILL_LAYOUT[row[0]]
            record: dict[str, object] = {"table": table, "session_id": self._session_id}
            record.update(zip(columns, row[1:], strict=False))
            if row[0] in (_SAMPLE, _END):
                record["cast_id"] = self._stored_id(row[1], {})
            elif row[0] == _EVENT:
                record["detail_json"] = self._event_detail(row, {})
            return json.dumps(record, default=repr)
        except Exception:
            return json.dumps({"table": None, "row": repr(row)})
