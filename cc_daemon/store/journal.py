"""The survey journal's records: fixes, casts, samples, events and sonar readings.

This module owns what the journal holds: the `Journal` API the daemon calls from
its loop (`record_fix`, `start_cast`, `record_sample`, `end_cast`, `record_event`,
`record_sonar`), the rows and SQL, the session each run opens (its survey), and
closing the casts a crash left open. Every call stamps its row (monotonic time,
wall-clock UTC, whether the clock looked synchronised), hands it to the buffered
writer (`writer.BufferedWriter`) and returns in about a microsecond; it never raises
into the daemon, nor drops a cast sample while a fix or an event could go instead.

Fixes are thinned to `telemetry_rate_hz` (`thinning.FixThinner`: the latest of each
interval kept, the rest counted in a `telemetry_thinned` event at most every minute)
and the buffer sized from it: no input fills the disk or the memory past a bound
(`fixes.FixJournal`, which this builds on).
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cc_daemon.core.protocol import StartMeasuring
from cc_daemon.ground.clocksync import clock_sync
from cc_daemon.store import sonde
from cc_daemon.store.buffer import FIX, Row
from cc_daemon.store.failures import emit
from cc_daemon.store.fixes import FixJournal
from cc_daemon.store.health import JournalHealth
from cc_daemon.store.rows import (
    CAST,
    END,
    EVENT,
    INSERT_CAST,
    INSERT_EVENT,
    INSERT_FIX,
    INSERT_SAMPLE,
    INSERT_SONAR,
    SAMPLE,
    SONAR,
    SPILL_LAYOUT,
    UPDATE_END,
)
from cc_daemon.store.sessions import close_unfinished, open_session, session_exists
from cc_daemon.store.spill import DEFAULT_FILE_MODE

PHASES = frozenset({"soaking", "descending", "dwelling", "ascending", "aborting", "stranded"})
OUTCOMES = frozenset({"completed", "skipped-shallow", "aborted", "unfinished"})
SYNC_CHECK_INTERVAL_S = 1.0
UNFINISHED_REASON = "no end recorded: the daemon stopped during the cast (crash, kill or power cut)"


def _kernel_says_synced() -> bool:
    return clock_sync().synchronised is True


def default_store_path() -> Path:
    """`$STATE_DIRECTORY/cc-daemon.db` under systemd, else `./cc-daemon.db`."""
    # systemd joins several StateDirectory= entries with ':'; the first is ours.
    state = os.environ.get("STATE_DIRECTORY", "").split(":")[0]
    return Path(state) / "cc-daemon.db" if state else Path("cc-daemon.db")


def _to_json(value: object) -> str:
    # default=str: a plan or event detail holding a Path, an enum or a
    # datetime is stored readably instead of failing the whole row.
    return json.dumps(value, default=str, sort_keys=True, separators=(",", ":"))


class Journal(FixJournal):
    """The survey journal. Construct, `open()`, record from the loop, `close()`.

    Call `open()` and `close()` from the thread that owns the daemon's start and
    stop (they are synchronous; `open` may migrate a large file). All the other
    methods are for the asyncio loop thread and return in microseconds.
    """

    # When the buffer is full: after the fixes, events go, then samples, then the
    # sonde's readings (what the boat stops for); casts never.
    # Sonar readings are bulk rows like the fixes: written and shed with them.
    shed_order = (EVENT, SAMPLE, sonde.SONDE)
    bulk_kinds = frozenset({FIX, SONAR})

    def __init__(
        self,
        path: Path,
        *,
        monotonic: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        clock_synced: Callable[[], bool] | None = None,
        max_buffered_rows: int | None = None,
        on_connect: Callable[[sqlite3.Connection], None] | None = None,
        winch_backend: str | None = None,
        simulated: bool | None = None,
        telemetry_rate_hz: float | None = None,
        spill_dir: Path | None = None,
        file_mode: int = DEFAULT_FILE_MODE,
    ) -> None:
        """`on_connect` is called with every new connection before use (tests use it
        to set `PRAGMA max_page_count`, which makes SQLite report a full disk).
        `winch_backend` and `simulated` go on the session and on every cast (None:
        not recorded). `telemetry_rate_hz` and `max_buffered_rows`: `fixes.FixJournal`.
        """
        super().__init__(
            path,
            monotonic=monotonic,
            telemetry_rate_hz=telemetry_rate_hz,
            max_buffered_rows=max_buffered_rows,
            wall=wall,
            on_connect=on_connect,
            spill_dir=spill_dir,
            file_mode=file_mode,
        )
        # The same answer `cc-daemon status` gives: the kernel's (adjtimex), which
        # every time daemon sets, else timesyncd's flag file.
        self._clock_synced_now = clock_synced or _kernel_says_synced
        self._winch_backend = winch_backend
        self._simulated = None if simulated is None else int(simulated)
        self._next_cast_id = 1  # guarded by _lock: the writer raises it past the file's

        # Loop-thread only.
        self._sync_checked_at = -float("inf")
        self._synced = 0
        self._open_casts: set[int] = set()

        # Writer only (open() uses them before the writer starts).
        self._session_id: int | None = None
        self._recovered = False
        self.recovered: list[int] = []  # casts this open found with no end (a crash)
        self._id_map: dict[int, int] = {}
        # Start rows of casts committed but not yet ended, by the id they were
        # recorded with: written again if the run moves to a fresh file.
        self._unended: dict[int, Row] = {}

    @property
    def session_id(self) -> int | None:  # this run's survey, once the file is open
        return self._session_id

    def health(self) -> JournalHealth:
        with self._lock:  # pending and written from the same instant
            spilled = self._spilled.rows
            pending = self._pending_locked() + spilled
            written = self._rows_written
        thread = self._thread
        stalled = self._stalled_s()
        last_error = self._last_error
        if stalled is not None:  # a frozen filesystem: the write has not come back
            last_error = f"journal write not done after {stalled:.0f} s (filesystem frozen?)"
        return JournalHealth(
            path=self._active,
            writable=self._conn is not None and not self._failing and stalled is None,
            pending_rows=pending,
            rows_written=written,
            write_errors=self._write_errors,
            dropped_rows=self._dropped_rows,
            last_error=last_error,
            writer_alive=thread is not None and thread.is_alive(),
            spilled_rows=spilled,
            spill_files=tuple(self._spilled.files),
        )

    def _episode_ended(self, **detail: object) -> None:
        """Journal the episode of failure that just ended (a full disk, say)."""
        self.record_event("journal_unwritable", **detail)

    # ------------------------------------------------- loop-thread recording
    # Each method catches every exception: the journal's contract is that it
    # never takes the daemon down, and a bad argument or an injected clock that
    # fails is logged instead of ending a cast. Logging itself never raises.

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
            row = (CAST, cast_id, mono, self._wall(), self._clock_synced(mono), *station[:6])
            winch = (self._winch_backend, self._simulated)
            self._append((*row, planned_depth_m, mode, plan_json, *winch))
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
                (SAMPLE, cast_id, mono, self._wall(), self._clock_synced(mono), depth_m, phase)
            )
        except Exception as exc:
            self._errors.error(
                "record_sample", "journal could not record a sample", error=repr(exc)
            )

    def record_sonde_sample(
        self,
        *,
        cast_id: int | None,
        phase: str,
        mono_s: float,
        wall_s: float,
        duration_s: float,
        status: str,
        error: str | None,
        line_out_m: float | None,
        sonde_depth_m: float | None,
        values: dict[str, float | None],
        missing: dict[str, str],
        simulated: bool,
    ) -> None:
        """One sonde reading, stamped with the times its request went out (`store.sonde`)."""
        try:
            row = sonde.build_row(
                cast_id=cast_id,
                phase=phase,
                mono_s=mono_s,
                wall_s=wall_s,
                clock_synced=self._clock_synced(mono_s),
                duration_s=duration_s,
                status=status,
                error=error,
                line_out_m=line_out_m,
                sonde_depth_m=sonde_depth_m,
                simulated=simulated,
                values=values,
                missing=missing,
            )
            self._append(row)
        except Exception as exc:
            self._errors.error(
                "record_sonde_sample", "journal could not record a sonde reading", error=repr(exc)
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
                    END,
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

    def record_sonar(self, port: str, distance_mm: int, confidence_pct: int) -> None:
        """One reading of the daemon's own sonar (`[sonar]`), as it arrived."""
        try:
            mono = self._monotonic()
            row = (SONAR, mono, self._wall(), self._clock_synced(mono), port)
            self._append((*row, distance_mm, confidence_pct))
        except Exception as exc:
            self._errors.error(
                "record_sonar", "journal could not record a sonar reading", error=repr(exc)
            )

    def record_event(self, kind: str, **detail: object) -> None:
        """A link or fault event (`port_lost`, `winch_fault`, ...) with its details.

        A `cast_id` in the details follows the cast if it is stored under a new id.
        """
        try:
            mono = self._monotonic()
            ref = detail.get("cast_id")
            row = (
                EVENT,
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
        # One adjtimex a second at most: the kernel's sync state changes rarely.
        if not 0.0 <= mono - self._sync_checked_at < SYNC_CHECK_INTERVAL_S:
            self._sync_checked_at = mono
            self._synced = self._ask_clock_synced()
        return self._synced

    def _ask_clock_synced(self) -> int:
        try:
            return 1 if self._clock_synced_now() else 0
        except Exception:  # never into the daemon: an unknown clock is not a synchronised one
            return 0

    # ------------------------------------------------- the writer's hooks

    def _prepare(self, conn: sqlite3.Connection) -> list[tuple[int, int, float | None]]:
        """A session row for this run; the first time, close casts a crash left open."""
        self._ensure_session(conn)
        found = [] if self._recovered else close_unfinished(conn, UNFINISHED_REASON)
        max_id = conn.execute("SELECT coalesce(max(id), 0) FROM casts").fetchone()[0]
        with self._lock:
            self._next_cast_id = max(self._next_cast_id, int(max_id) + 1)
        return found

    def _connected(self, path: Path, prepared: Any) -> list[int]:
        self._recovered = True
        for cast_id, samples, reached in prepared:
            emit(
                "warning",
                "cast left unfinished by a crash; marked unfinished",
                cast_id=cast_id,
                samples=samples,
                reached_depth_m=reached,
                path=str(path),
            )
        self.recovered = [cast_id for cast_id, _, _ in prepared]
        return self.recovered

    def _committed(self, rows: list[Row], refused: set[int], new_ids: dict[int, int]) -> None:
        self._id_map.update(new_ids)
        for row in rows:
            if row[0] == CAST and id(row) not in refused:
                self._unended[row[1]] = row
            elif row[0] == END:
                self._unended.pop(row[1], None)

    def _rows_to_rewrite(self) -> list[Row]:
        # Casts still running when the old file failed: their samples and
        # ends go to the fresh file, so their start rows (the station) must too.
        rows = list(self._unended.values())
        self._unended.clear()
        return rows

    def _ensure_session(self, conn: sqlite3.Connection) -> None:
        if self._session_id is not None and session_exists(conn, self._session_id):
            return
        self._session_id = open_session(
            conn,
            monotonic=self._monotonic(),
            wall=self._wall(),
            clock_synced=self._ask_clock_synced(),
            winch_backend=self._winch_backend,
            simulated=self._simulated,
        )

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
        if kind == FIX:
            conn.execute(INSERT_FIX, (self._session_id, *row[1:]))
        elif kind == SONAR:
            conn.execute(INSERT_SONAR, (self._session_id, *row[1:]))
        elif kind == SAMPLE:
            conn.execute(INSERT_SAMPLE, (self._stored_id(row[1], new_ids), *row[2:]))
        elif kind == CAST:
            self._insert_cast(conn, row, new_ids)
        elif kind == END:
            cursor = conn.execute(UPDATE_END, (*row[2:], self._stored_id(row[1], new_ids)))
            if cursor.rowcount == 0:
                self._errors.error(
                    "end-unknown",
                    "journal: end of a cast that is not in the file",
                    cast_id=row[1],
                )
        elif kind == EVENT:
            detail_json = self._event_detail(row, new_ids)
            conn.execute(INSERT_EVENT, (self._session_id, *row[1:5], detail_json))
        elif kind == sonde.SONDE:
            cast_id = None if row[1] is None else self._stored_id(row[1], new_ids)
            conn.execute(sonde.INSERT, (self._session_id, cast_id, *row[2:]))
        else:
            raise ValueError(f"unknown journal row kind {kind!r}")

    def _insert_cast(self, conn: sqlite3.Connection, row: Row, new_ids: dict[int, int]) -> None:
        cast_id = row[1]
        # A cast written again into a fresh file keeps the id it was stored under.
        wanted = self._id_map.get(cast_id, cast_id)
        taken = conn.execute("SELECT 1 FROM casts WHERE id = ?", (wanted,)).fetchone()
        if not taken:
            conn.execute(INSERT_CAST, (wanted, self._session_id, *row[2:]))
            return
        # The id was handed out while the file could not be read (so the last
        # id in it was unknown), or another process wrote the same file: store
        # the cast under a fresh id and send its samples, end and events there too.
        cursor = conn.execute(INSERT_CAST, (None, self._session_id, *row[2:]))
        assert cursor.lastrowid is not None
        new_ids[cast_id] = cursor.lastrowid
        with self._lock:  # ids handed out from now on must not meet this one
            self._next_cast_id = max(self._next_cast_id, cursor.lastrowid + 1)
        emit(
            "warning",
            "journal: cast id already in the file; stored under a new id",
            cast_id=cast_id,
            stored_as=cursor.lastrowid,
            path=str(self._active),
        )

    def _spill_line(self, row: Row) -> str:
        try:
            table, columns = SPILL_LAYOUT[row[0]]
            record: dict[str, object] = {"table": table, "session_id": self._session_id}
            record["row"] = list(row)  # as recorded: what this run replays
            record.update(zip(columns, row[1:], strict=False))
            if row[0] in (SAMPLE, END) or (row[0] == sonde.SONDE and row[1] is not None):
                record["cast_id"] = self._stored_id(row[1], {})
            elif row[0] == EVENT:
                record["detail_json"] = self._event_detail(row, {})
            return json.dumps(record, default=repr)
        except Exception:
            return json.dumps({"table": None, "row": repr(row)})
