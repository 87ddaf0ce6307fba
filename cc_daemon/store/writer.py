"""The journal's writer: a thread of its own that moves buffered rows into SQLite.

It owns getting rows into the file and keeping them safe until they are there:
the thread and its one connection, transactions, durability, a nearly full
disk, retries, fresh files, the spill file at close. What rows mean is the
subclass's (`journal.Journal`); they wait in a `buffer.RowBuffer` meanwhile.
It must never block the event loop, nor raise into the daemon because storage
or logging failed (disk full, read-only, locked, missing, corrupt; a lost log).

Durability. Non-fix rows (a cast's rows, events) wake the writer at once and
are committed with `synchronous=FULL`: on disk within milliseconds, surviving
`kill -9` and a power cut. Fixes are committed at least every
`FLUSH_INTERVAL_S` with `synchronous=NORMAL` (in the WAL, so they survive a
kill, not fsynced); the WAL is append-only, so the next FULL commit makes every
earlier frame durable, and one is forced at least every `FULL_SYNC_INTERVAL_S`:
at most 6 s of telemetry lost to a power cut, four fsyncs in five spared.

Transactions hold at most `MAX_TRANSACTION_ROWS` rows, cast rows and events
first, so a backlog never has to fit on the disk at once (cast rows that do not
fit are retried in halves). Below `LOW_SPACE_BYTES` free the WAL is truncated
after every transaction; below `FIX_RESERVE_BYTES` fixes wait in memory.

When writing fails the rows stay buffered, the error is logged at most every
`LOG_INTERVAL_S` with a count, and the writer retries every `RETRY_INTERVAL_S`.
A file that can never be used (corrupt, another program's, a newer version's) is
left untouched for a fresh one beside it (`health().path` names it). Rows unwritten
at close go to a JSON-lines spill file (`spill.py`), never in the temporary
directory (PrivateTmp wipes it) nor under /dev, /proc or /sys.
"""

from __future__ import annotations

import contextlib
import sqlite3
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Self

from cc_daemon.store import schema
from cc_daemon.store.buffer import FIX, Row
from cc_daemon.store.failures import (
    ROW_ERRORS,
    STORAGE_ERRORS,
    data_directories,
    emit,
    free_bytes,
    is_full,
    is_permanent,
    state_directories,
    unused_path,
    utc_stamp,
)
from cc_daemon.store.spill import DEFAULT_FILE_MODE, create_file
from cc_daemon.store.spillover import MAX_TRANSACTION_ROWS, SpillOver

FLUSH_INTERVAL_S = 1.0
FULL_SYNC_INTERVAL_S = 5.0
RETRY_INTERVAL_S = 1.0
# A lock wait blocks nobody else (a thread); 0.5 s rides out a reader's checkpoint.
BUSY_TIMEOUT_S = 0.5
# Below this much free space the WAL is checkpointed and truncated after every
# transaction (it normally grows to some 4 MB first): a WAL that has taken the
# last free bytes cannot even be checkpointed, since that grows the file.
LOW_SPACE_BYTES = 8 << 20
# Telemetry is not written while less than this is free on the journal's
# filesystem: the last of the disk is kept for casts (fixes wait in memory).
FIX_RESERVE_BYTES = 256 << 10


class BufferedWriter(SpillOver):
    """A journal file with a writer thread. Construct, `open()`, add rows, `close()`.

    Call `open()` and `close()` from the thread that owns the daemon's start and
    stop (they are synchronous; `open` may migrate a large file). Rows are added
    from the asyncio loop thread with `_append`, in microseconds.
    """

    def __init__(
        self,
        path: Path,
        *,
        wall: Callable[[], float],
        max_buffered_rows: int,
        on_connect: Callable[[sqlite3.Connection], None] | None,
        spill_dir: Path | None = None,
        file_mode: int = DEFAULT_FILE_MODE,
    ) -> None:
        super().__init__(path, max_buffered_rows, spill_dir, file_mode)
        self._wall = wall
        self._on_connect = on_connect
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._writer_running = False  # set before the thread starts, cleared as it ends
        self._writer_lock = threading.Lock()
        self._writer_restarted_at = -float("inf")
        self._closed = False

        # Writer only (open() uses them before the writer starts). The
        # counters are read by health() from the loop: int reads are atomic.
        self._conn: sqlite3.Connection | None = None
        self._replacements: list[Path] | None = None  # set once _active proved unusable
        self._failing = False
        self._sync_mode = ""
        self._last_full_sync = -float("inf")
        self._write_errors = 0

    # ------------------------------------------------- what the subclass adds

    def _prepare(self, conn: sqlite3.Connection) -> Any:
        """Inside the transaction that opens a file: make it ready for the rows."""
        return None

    def _connected(self, path: Path, prepared: Any) -> list[int]:
        """After a file opened; returns what `open()` reports (ids of casts recovered)."""
        return []

    def _insert(self, conn: sqlite3.Connection, row: Row, new_ids: dict[int, int]) -> None:
        raise TypeError(f"{type(self).__name__} cannot store row kind {row[0]!r}")

    def _committed(self, rows: list[Row], refused: set[int], new_ids: dict[int, int]) -> None:
        """After a transaction of non-fix rows committed (`refused`: ids of rows set aside)."""

    def _rows_to_rewrite(self) -> list[Row]:
        """Rows already committed to a file abandoned since, that the fresh one needs too."""
        return []

    def _before_pass(self) -> None:
        """Called by the writer thread before each pass (rows held back may be due)."""

    def _where(self) -> dict[str, str]:
        return {"path": str(self._active)}

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
            emit("error", "journal close failed", error=repr(exc), path=str(self._active))

    def _close(self, timeout: float) -> None:
        thread = self._thread
        if thread is not None:
            dead = not thread.is_alive()  # asked before it is told to stop, and does
            self._stop.set()
            self._wake.set()
            if dead:
                # The writer died: a new one makes the last attempt at the file.
                emit("error", "journal writer had stopped; restarting it to write what is left")
                with contextlib.suppress(Exception):
                    self._start_writer()
                    thread = self._thread
            assert thread is not None
            thread.join(timeout)
            if thread.is_alive():
                with self._lock:
                    rows = [*self._in_flight, *self._urgent, *self._fixes]
                spilled = self._spill(rows) if rows else None
                emit(
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
        self._spill_at_close(rows, opened=thread is not None)

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def _append(self, row: Row) -> None:
        # The writer's own rows (an episode's end, at its last pass) go in: one pass more.
        if self._closed and threading.current_thread() is not self._thread:
            self._errors.error("closed", "journal is closed; row not recorded", kind=row[0])
            return
        if self._buffer_row(row) and not self._wake.is_set():
            self._wake.set()
        if not self._writer_running and self._thread is not None:
            self._restart_writer()

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
            emit("error", "journal writer thread had stopped; restarted", path=str(self._active))
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
            emit("error", "journal writer stopped by an error", error=repr(exc))
        finally:
            with contextlib.suppress(Exception):
                self._disconnect()
            self._writer_running = False

    def _writer_loop(self) -> None:
        deadline = time.monotonic() + FLUSH_INTERVAL_S
        extra_pass = False
        while True:
            stopping = False
            try:
                stopping = self._stop.is_set()
                if not stopping:
                    if self._failing:
                        # Ignore wake-ups while failing: retry once a second, not per row.
                        self._stop.wait(RETRY_INTERVAL_S)
                        self._wake.clear()
                    else:
                        self._wait_for_rows(deadline, self._wake, self._stop)
                    stopping = self._stop.is_set()
                deadline = time.monotonic() + FLUSH_INTERVAL_S
                self._writer_pass()
            except Exception as exc:  # a bug here must not end the thread: rows would pile up
                self._errors.error("writer", "journal writer pass failed", error=repr(exc))
                if not stopping:
                    self._stop.wait(RETRY_INTERVAL_S)  # and must not spin either
            if stopping:
                if self._urgent and not self._failing and not extra_pass:  # rows this pass made
                    extra_pass = True
                    continue
                break

    def _writer_pass(self) -> None:
        self._before_pass()
        was_failing = self._failing
        if self._conn is None:
            try:
                self._busy_since = time.monotonic()
                self._open_file()
            except STORAGE_ERRORS as exc:
                self._fail(exc, "journal cannot be opened; keeping rows in memory")
                self._spill_pending()
                return
            finally:
                self._busy_since = None
        written_now = 0
        replay_error, replay_later = self._replay()
        if replay_error is not None:
            if is_permanent(replay_error):
                self._abandon(replay_error)
            self._fail(replay_error, "journal write failed; keeping rows in a spill file")
            return
        while True:
            with self._lock:
                chunk = self._take_chunk_locked(MAX_TRANSACTION_ROWS, urgent=True)
            if not chunk:
                # Cast rows and events are all in; now telemetry, if there is room.
                if not self._fixes or not self._room_for_fixes():
                    break
                with self._lock:
                    chunk = self._take_chunk_locked(MAX_TRANSACTION_ROWS, urgent=False)
                if not chunk:
                    break
            done = written = 0
            error: BaseException | None = None
            try:
                self._busy_since = time.monotonic()
                done, written, error = self._commit(chunk)
            finally:
                self._busy_since = None
                # Whatever happened, what was not committed goes back, in order.
                with self._lock:
                    self._rows_written += written
                    dropped = self._put_back_locked(chunk[done:])
                written_now += written
                if dropped:
                    self._count_dropped(dropped)
            if error is not None:
                if is_permanent(error):
                    self._abandon(error)
                self._fail(error, "journal write failed; keeping rows in memory")
                self._spill_pending()
                return
            free = self._free_bytes()
            if free is not None and free < LOW_SPACE_BYTES:
                self._checkpoint()
        if replay_later is not None:  # spilled telemetry still waits
            self._fail(replay_later, "journal write failed; keeping rows in a spill file")
            return
        self._failing = False
        if was_failing:
            self._last_error = None
            emit("info", "journal writable again", rows=written_now, path=str(self._active))
        episode, self._episode = self._episode, None
        if episode is not None:
            started, started_wall, first_error, dropped_before = episode
            self._episode_ended(
                started_wall=started_wall,
                seconds=round(time.monotonic() - started, 3),
                error=first_error,
                dropped_rows=self._dropped_rows - dropped_before,
            )

    def _free_bytes(self) -> int | None:
        return free_bytes(self._active.parent)

    def _room_for_fixes(self) -> bool:
        """Whether the filesystem has more than `FIX_RESERVE_BYTES` free (if it can tell)."""
        free = self._free_bytes()
        if free is None or free >= FIX_RESERVE_BYTES:
            if self._last_error is not None and self._last_error.startswith("disk nearly full"):
                self._last_error = None
            return True
        self._last_error = f"disk nearly full: {free} bytes free"
        self._errors.error(
            "reserve",
            "journal disk nearly full; telemetry held in memory to keep the space for casts",
            free_bytes=free,
            reserve_bytes=FIX_RESERVE_BYTES,
            pending_rows=self._pending_locked(),
            path=str(self._active),
        )
        return False

    def _commit(self, chunk: list[Row]) -> tuple[int, int, BaseException | None]:
        """Commit `chunk` from its front; cast rows on a full disk in smaller transactions.

        Returns how many rows from the front are done with (committed or refused
        by SQLite), how many of them were committed, and the storage error that
        stopped it, if one did.
        """
        size = len(chunk)
        halve = chunk[0][0] != FIX  # fixes wait for room whole; cast rows take what fits
        checkpointed = False
        done = written = 0
        while done < len(chunk):
            part = chunk[done : done + size]
            try:
                try:
                    written += self._write(part, one_by_one=False)
                except ROW_ERRORS:
                    written += self._write(part, one_by_one=True)
            except STORAGE_ERRORS as exc:
                if not is_full(exc):
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
            except STORAGE_ERRORS as exc:
                if not is_permanent(exc):
                    raise
                self._write_errors += 1
                self._last_error = f"{type(exc).__name__}: {exc}"
                self._abandon(exc)
        assert self._replacements is not None
        error: BaseException | None = None
        for candidate in self._replacements:
            try:
                found = self._connect(candidate)
            except STORAGE_ERRORS as exc:
                error = exc
                continue
            bad, self._active, self._replacements = self._active, candidate, None
            rewrite = self._rows_to_rewrite()
            if rewrite:
                with self._lock:
                    self._urgent[:0] = rewrite
            emit(
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
            stamp = utc_stamp(self._wall())
        except Exception:
            stamp = utc_stamp(time.time())
        name = f"{self.path.stem}-{stamp}{self.path.suffix or '.db'}"
        self._replacements = [unused_path(directory / name) for directory in self._fallback_dirs()]
        emit(
            "critical",
            "journal file cannot be used (corrupt, not a journal, or from a newer cc-daemon);"
            " leaving it untouched and starting a new file",
            path=str(bad),
            error=f"{type(exc).__name__}: {exc}",
            new_path=str(self._replacements[0]),
            pending_rows=self._pending_locked(),
        )

    def _fallback_dirs(self, *, temporary: bool = True) -> list[Path]:
        """Where a fresh file (or, without `temporary`, a spill file) may go."""
        candidates = [self._active.parent, self.path.parent, *state_directories()]
        if temporary:
            with contextlib.suppress(Exception):  # no usable temporary directory at all
                candidates.append(Path(tempfile.gettempdir()))
        return data_directories(candidates)

    def _connect(self, path: Path) -> list[int]:
        """Open the file and make it ready (`_prepare`), then tell `_connected`."""
        if not path.exists():
            # SQLite gives -wal and -shm the mode of the file: one rule for all three.
            create_file(path, self._file_mode)
        conn = sqlite3.connect(
            path,
            timeout=BUSY_TIMEOUT_S,
            isolation_level=None,  # explicit BEGIN/COMMIT: we decide what a transaction holds
            check_same_thread=False,  # open() connects, then hands over to the writer thread
        )
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
                emit("info", "journal migrated", path=str(path), from_version=old, to_version=new)
            conn.execute("BEGIN IMMEDIATE")
            try:
                prepared = self._prepare(conn)
                conn.execute("COMMIT")
            except BaseException:
                if conn.in_transaction:
                    conn.execute("ROLLBACK")
                raise
        except BaseException:
            conn.close()
            raise
        self._conn = conn
        self._sync_mode = ""
        self._failing = False
        return self._connected(path, prepared)

    def _write(self, rows: list[Row], *, one_by_one: bool) -> int:
        """Commit `rows` in one transaction; one by one, setting aside rows SQLite refuses.

        Returns how many rows were committed.
        """
        conn = self._conn
        assert conn is not None
        now = time.monotonic()
        durable = now - self._last_full_sync >= FULL_SYNC_INTERVAL_S or any(
            row[0] != FIX for row in rows
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
                except ROW_ERRORS as exc:
                    conn.execute("ROLLBACK TO one_row")
                    refused.append((row, exc))
                conn.execute("RELEASE one_row")
            conn.execute("COMMIT")
        except BaseException:
            if conn.in_transaction:
                with contextlib.suppress(sqlite3.Error):
                    conn.execute("ROLLBACK")
            raise
        if durable:
            self._last_full_sync = now
        if rows[0][0] != FIX:  # transactions hold fixes only, or none
            self._committed(rows, {id(row) for row, _ in refused}, new_ids)
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

    def _fail(self, exc: BaseException, event: str) -> None:
        self._write_errors += 1
        self._last_error = f"{type(exc).__name__}: {exc}"
        self._failing = True
        if self._episode is None:
            wall = time.time()
            with contextlib.suppress(Exception):
                wall = self._wall()
            self._episode = (time.monotonic(), wall, self._last_error, self._dropped_rows)
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
