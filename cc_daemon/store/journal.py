"""The survey journal's write side: fixes, casts, samples and events into SQLite.

This module owns getting rows from the daemon into the journal file and
keeping them safe until they are there. The daemon calls `Journal` from its
asyncio loop; every `record_*`, `start_cast` and `end_cast` stamps the row
(monotonic time, wall-clock UTC, whether the clock looked synchronised) and
appends it to an in-memory list under a lock, in about a microsecond. One
writer thread with its own `sqlite3` connection drains that list into the file.

It must never block the event loop, never raise into the daemon because
storage failed (disk full, read-only, locked, missing, corrupt), and never
drop a cast sample while a telemetry fix or an event could be dropped instead.

Durability. Rows that belong to a cast (start, samples, end) and events wake
the writer at once and are committed with `synchronous=FULL`, so they are on
disk within milliseconds and survive `kill -9` and a power cut. Telemetry is
committed at least every `FLUSH_INTERVAL_S` with `synchronous=NORMAL`: in WAL
mode a NORMAL commit is in the WAL file (so it survives the process being
killed) but the WAL is not fsynced, so a power cut could lose it. The WAL is
append-only, so the next FULL commit's fsync makes every earlier frame durable
too; the writer forces a FULL commit at least every `FULL_SYNC_INTERVAL_S`,
which bounds telemetry lost to a power cut to that many seconds (the issue
allows 10) while sparing the SD card four fsyncs out of five between casts.

When writing fails, the rows stay in memory (at most `max_buffered_rows`;
beyond that the oldest fixes go first, then events, then samples; cast start
and end rows are never dropped), the error is logged at most every
`LOG_INTERVAL_S` with a count of repeats, and the writer reconnects and
retries every `RETRY_INTERVAL_S`.
"""

from __future__ import annotations

import contextlib
import json
import os
import sqlite3
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
UNFINISHED_REASON = "no end recorded: the daemon stopped during the cast (crash, kill or power cut)"

# Row kinds. A row is a tuple: the kind, then its values in the order of the
# matching INSERT (tuples are the cheapest thing to build on the loop thread).
_FIX = 0
_CAST = 1
_SAMPLE = 2
_END = 3
_EVENT = 4
# Which rows to sacrifice first when the buffer is full; casts never.
_SHED_ORDER = (_FIX, _EVENT, _SAMPLE)

Row = tuple[Any, ...]

_INSERT_FIX = (
    "INSERT INTO fixes (session_id, mono_s, wall_s, clock_synced, frame, ap_timestamp_s,"
    " lon_e7, lat_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct)"
    " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)"
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

# A problem with one row (a value SQLite cannot bind, a constraint): retrying
# the same row can never succeed, so such rows are set aside one by one.
# Everything else (OperationalError: full, read-only, locked, I/O; a corrupt
# file; OSError) is about the storage and worth retrying.
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

    path: Path
    writable: bool  # the file is open and the last write succeeded
    pending_rows: int  # recorded but not yet committed
    rows_written: int
    write_errors: int  # failed attempts to open or write the file
    dropped_rows: int  # given up for good: buffer overflow or a row SQLite refused
    last_error: str | None


def default_store_path() -> Path:
    """`$STATE_DIRECTORY/cc-daemon.db` under systemd, else `./cc-daemon.db`."""
    # systemd joins several StateDirectory= entries with ':'; the first is ours.
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return Path(state) / "cc-daemon.db" if state else Path("cc-daemon.db")


class _RateLimitedLog:
    """Error logging that says a repeated error once per interval, with a count.

    Repeats are never silenced: the next message carries how many were held
    back. Used from the loop thread and the writer thread, hence the lock.
    """

    def __init__(self, interval_s: float) -> None:
        self._interval_s = interval_s
        self._lock = threading.Lock()
        self._last: dict[str, tuple[float, int]] = {}

    def error(self, key: str, event: str, **fields: Any) -> None:
        now = time.monotonic()
        with self._lock:
            last, held = self._last.get(key, (-float("inf"), 0))
            if now - last < self._interval_s:
                self._last[key] = (last, held + 1)
                return
            self._last[key] = (now, 0)
        if held:
            fields["repeated"] = held
        log.error(event, **fields)


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
        self.path = Path(path)
        self._monotonic = monotonic
        self._wall = wall
        self._timesync_flag = str(timesync_flag)
        self._max_rows = max_buffered_rows
        self._on_connect = on_connect

        # Shared between the loop thread and the writer: guarded by _lock.
        self._lock = threading.Lock()
        self._incoming: list[Row] = []
        self._next_cast_id = 1
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False

        # Loop-thread only.
        self._sync_checked_at = -float("inf")
        self._synced = 0
        self._open_casts: set[int] = set()

        # Writer only (open() uses them before the writer starts). The
        # counters are read by health() from the loop: int reads are atomic.
        self._conn: sqlite3.Connection | None = None
        self._session_id: int | None = None
        self._recovered = False
        self._backlog: list[Row] = []
        self._id_map: dict[int, int] = {}
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
        unfinished then are marked and logged when the file first opens).
        """
        if self._thread is not None or self._closed:
            raise RuntimeError("Journal.open() called twice or after close()")
        recovered: list[int] = []
        try:
            recovered = self._connect()
        except Exception as exc:  # whatever it is, the daemon must start: log, retry later
            self._fail(exc, "journal cannot be opened; keeping rows in memory")
        self._thread = threading.Thread(
            target=self._writer_main, name="cc-daemon-journal", daemon=True
        )
        self._thread.start()
        return recovered

    def close(self, timeout: float = 5.0) -> None:
        """Write what can be written (waiting up to `timeout` s), stop the writer, close."""
        if self._closed:
            return
        self._closed = True
        thread = self._thread
        if thread is None:
            pending = len(self._incoming)
            if pending:
                log.error("journal closed before it was opened; rows lost", rows=pending)
            return
        self._stop.set()
        self._wake.set()
        thread.join(timeout)
        if thread.is_alive():
            log.error(
                "journal writer did not finish in time; unwritten rows may be lost",
                timeout_s=timeout,
                pending_rows=len(self._incoming) + len(self._backlog),
                path=str(self.path),
            )

    def __enter__(self) -> Journal:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def health(self) -> JournalHealth:
        return JournalHealth(
            path=self.path,
            writable=self._conn is not None and not self._failing,
            pending_rows=len(self._incoming) + len(self._backlog),
            rows_written=self._rows_written,
            write_errors=self._write_errors,
            dropped_rows=self._dropped_rows,
            last_error=self._last_error,
        )

    # ------------------------------------------------- loop-thread recording
    # Each method catches every exception: the journal's contract is that it
    # never takes the daemon down, and a bad argument or an injected clock that
    # fails is logged instead of ending a cast.

    def record_fix(self, msg: Telemetry | StartMeasuring) -> None:
        """A telemetry fix (`P-T`) or a start-measuring frame (`P-M`), as received."""
        try:
            mono = self._monotonic()
            self._append((_FIX, mono, self._wall(), self._clock_synced(mono), msg.frame, *msg))
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
            row = (_CAST, cast_id, mono, self._wall(), self._clock_synced(mono), *station)
            self._append((*row, planned_depth_m, mode, plan_json), urgent=True)
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
                (_SAMPLE, cast_id, mono, self._wall(), self._clock_synced(mono), depth_m, phase),
                urgent=True,
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
                ),
                urgent=True,
            )
        except Exception as exc:
            self._errors.error("end_cast", "journal could not record a cast end", error=repr(exc))

    def record_event(self, kind: str, **detail: object) -> None:
        """A link or fault event (`port_lost`, `winch_fault`, ...) with its details."""
        try:
            mono = self._monotonic()
            row = (_EVENT, mono, self._wall(), self._clock_synced(mono), kind, _to_json(detail))
            self._append(row, urgent=True)
        except Exception as exc:
            self._errors.error("record_event", "journal could not record an event", error=repr(exc))

    def _clock_synced(self, mono: float) -> int:
        # A stat() a second at most: the flag changes once per boot or so.
        if not 0.0 <= mono - self._sync_checked_at < SYNC_CHECK_INTERVAL_S:
            self._sync_checked_at = mono
            self._synced = 1 if os.path.exists(self._timesync_flag) else 0
        return self._synced

    def _append(self, row: Row, *, urgent: bool = False) -> None:
        if self._closed:
            self._errors.error("closed", "journal is closed; row not recorded", kind=row[0])
            return
        with self._lock:
            self._incoming.append(row)
            backed_up = len(self._incoming) > self._max_rows
        if backed_up:
            # The writer sheds the whole buffer every pass; getting here means
            # it has been stuck inside one write for a whole buffer's worth of
            # rows. Shed to 90 % so this runs once per many rows, not per row.
            with self._lock:
                self._incoming, dropped = _shed(
                    self._incoming, len(self._incoming) - self._max_rows * 9 // 10
                )
            self._count_dropped(dropped)
        if urgent and not self._wake.is_set():
            self._wake.set()

    def _count_dropped(self, dropped: int) -> None:
        if dropped:
            with self._lock:  # both threads drop rows
                self._dropped_rows += dropped
                total = self._dropped_rows
            self._errors.error(
                "dropped",
                "journal buffer full; oldest rows dropped",
                dropped_rows=total,
                max_buffered_rows=self._max_rows,
                path=str(self.path),
            )

    # ------------------------------------------------------------- writer

    def _writer_main(self) -> None:
        deadline = time.monotonic() + FLUSH_INTERVAL_S
        while True:
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
            try:
                self._writer_pass()
            except Exception as exc:  # a bug here must not end the thread: rows would pile up
                self._errors.error("writer", "journal writer pass failed", error=repr(exc))
            if stopping:
                break
        self._disconnect()
        if self._backlog:
            log.error(
                "journal closed with rows it could not write; they are lost",
                rows=len(self._backlog),
                path=str(self.path),
                last_error=self._last_error,
            )

    def _writer_pass(self) -> None:
        was_failing = self._failing
        with self._lock:
            incoming, self._incoming = self._incoming, []
        self._backlog.extend(incoming)
        excess = len(self._backlog) - self._max_rows
        if excess > 0:
            self._backlog, dropped = _shed(self._backlog, excess)
            self._count_dropped(dropped)
        if self._conn is None:
            try:
                self._connect()
            except _STORAGE_ERRORS as exc:
                self._fail(exc, "journal cannot be opened; keeping rows in memory")
                return
        rows = self._backlog
        if rows:
            try:
                try:
                    written = self._write(rows, one_by_one=False)
                except _ROW_ERRORS:
                    written = self._write(rows, one_by_one=True)
            except _STORAGE_ERRORS as exc:
                self._fail(exc, "journal write failed; keeping rows in memory")
                return
            self._backlog = []
            self._rows_written += written
        self._failing = False
        if was_failing:
            log.info("journal writable again", rows=len(rows), path=str(self.path))

    def _connect(self) -> list[int]:
        """Open the file and make it ready; the first time, close casts a crash left open."""
        conn = sqlite3.connect(
            self.path,
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
                log.info("journal migrated", path=str(self.path), from_version=old, to_version=new)
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
            log.warning(
                "cast left unfinished by a crash; marked unfinished",
                cast_id=cast_id,
                samples=samples,
                reached_depth_m=reached,
                path=str(self.path),
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

    def _insert(self, conn: sqlite3.Connection, row: Row, new_ids: dict[int, int]) -> None:
        kind = row[0]
        if kind == _FIX:
            conn.execute(_INSERT_FIX, (self._session_id, *row[1:]))
        elif kind == _SAMPLE:
            cast_id = new_ids.get(row[1]) or self._id_map.get(row[1], row[1])
            conn.execute(_INSERT_SAMPLE, (cast_id, *row[2:]))
        elif kind == _CAST:
            self._insert_cast(conn, row, new_ids)
        elif kind == _END:
            cast_id = new_ids.get(row[1]) or self._id_map.get(row[1], row[1])
            cursor = conn.execute(_UPDATE_END, (*row[2:], cast_id))
            if cursor.rowcount == 0:
                self._errors.error(
                    "end-unknown",
                    "journal: end of a cast that is not in the file",
                    cast_id=row[1],
                )
        elif kind == _EVENT:
            conn.execute(_INSERT_EVENT, (self._session_id, *row[1:]))
        else:
            raise ValueError(f"unknown journal row kind {kind!r}")

    def _insert_cast(self, conn: sqlite3.Connection, row: Row, new_ids: dict[int, int]) -> None:
        cast_id = row[1]
        taken = conn.execute("SELECT 1 FROM casts WHERE id = ?", (cast_id,)).fetchone()
        if not taken:
            conn.execute(_INSERT_CAST, (cast_id, self._session_id, *row[2:]))
            return
        # The id was handed out while the file could not be read (so the last
        # id in it was unknown), or another process wrote the same file: store
        # the cast under a fresh id and send its samples and end there too.
        cursor = conn.execute(_INSERT_CAST, (None, self._session_id, *row[2:]))
        assert cursor.lastrowid is not None
        new_ids[cast_id] = cursor.lastrowid
        with self._lock:  # ids handed out from now on must not meet this one
            self._next_cast_id = max(self._next_cast_id, cursor.lastrowid + 1)
        log.warning(
            "journal: cast id already in the file; stored under a new id",
            cast_id=cast_id,
            stored_as=cursor.lastrowid,
            path=str(self.path),
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
            pending_rows=len(self._incoming) + len(self._backlog),
            path=str(self.path),
        )

    def _disconnect(self) -> None:
        # Reconnecting after a failure is what clears a read-only or replaced
        # file: an open connection keeps the mode and inode it started with.
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(sqlite3.Error):
                conn.close()
