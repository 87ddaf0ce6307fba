"""The journal's read side: one consistent, bounded view of a journal file.

This module owns opening a journal file for the data commands and the field
page, and the queries that give its rows back as records (`store.records`). It
must never write to the file: it opens it read-only (SQLite `mode=ro`), so it
can run beside the daemon (WAL lets one writer and readers work at once) and
never marks a running cast `unfinished` (only the daemon's `Journal.open()` may
decide that a cast was left by a crash). A file from an older cc-daemon is
migrated in a private copy, never in place.

A journal with no write-ahead log beside it is one nobody has open (SQLite
removes `-wal` and `-shm` with the last connection): the reader opens it
`immutable`, which reads the file alone and creates nothing beside it, so a
data command leaves no `-wal`/`-shm` behind and needs no write access to the
directory. That is safe because a daemon that starts meanwhile writes to its
new log, not to the file, until a checkpoint (4 MB of log, or its close). With
a log present (the daemon running, or killed) the reader opens it `mode=ro`,
using the `-shm` that is there; if it cannot (a directory it may not write, or
a `-shm`/`-journal` that is not a file), it reads a private copy of the file
and its log in a temporary directory.

The file may come from anyone: its files are judged before SQLite opens them
(`store.files`: a log that is a FIFO or a device is not read), every statement
is bounded in time and every value in size, and every table must be a real
table of the journal's shape (`store.guard`). A damaged file (SQLite's check,
the log's frames) is read from a salvaged copy; both are done once per change
of the file (`store.salvaged`). What could not be read is said in one line
when the reader closes (`damage_report`).

All the reads of one `JournalReader` see one snapshot of the file, so a cast
and its samples agree even while the daemon is writing.
"""

from __future__ import annotations

import os
import sqlite3
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Self, TypeVar

from cc_daemon.store import (
    damage,
    files,
    guard,
    records,
    schema,
    scratch,
    sonar,
    sonde,
    stationrows,
    surveys,
)
from cc_daemon.store import stations as station_rules
from cc_daemon.store.damage import Salvage
from cc_daemon.store.records import (
    CastRecord,
    EventRecord,
    FixRecord,
    SampleRecord,
    iso_utc,
    parse_time,
)
from cc_daemon.store.salvaged import Salvaged, shared
from cc_daemon.store.schema import StoreError
from cc_daemon.store.surveys import SurveyRecord, choose_survey

__all__ = [
    "CastRecord",
    "DamagedJournalError",
    "EventRecord",
    "FixRecord",
    "JournalReader",
    "SampleRecord",
    "iso_utc",
    "parse_time",
]

R = TypeVar("R")


class DamagedJournalError(StoreError):
    """The journal is damaged: what could not be read, in one line."""


# SQLite's primary result codes for "may not write here" and "cannot open".
_SQLITE_READONLY = 8
_SQLITE_CANTOPEN = 14
# Copying a file the daemon checkpoints at that moment can give a mismatched
# pair (file, log): copy again, this many times at most.
_COPY_ATTEMPTS = 5
# An older journal bigger than this is migrated in a private file, not in memory.
MIGRATE_IN_MEMORY_MAX = 64 << 20


class JournalReader:
    """A read-only, consistent view of one journal file. Use as a context manager."""

    def __init__(
        self,
        path: Path,
        *,
        survey: int | None = None,
        query_s: float | None = None,
        cache: Salvaged | None = None,
    ) -> None:
        """`survey`: read only that survey's rows (a session's id; None: every row).
        `query_s`: each statement's time bound (default `guard.QUERY_S`). `cache`: where
        checks and salvaged copies are kept (default: the process's own)."""
        self.path = Path(path)
        self.survey = survey
        self._query_s = query_s
        self._cache = cache if cache is not None else shared()
        self._private: Path | None = None
        self._bad_text = 0
        self._bad_rows: dict[str, int] = {}
        self._bad_json: dict[str, int] = {}
        self.salvage: Salvage | None = None  # set when read from a salvaged copy
        self.problems: list[str] = []
        found = files.inspect(self.path)  # StoreError: no journal, or not a file
        try:
            self._use(self._open(found))
        except StoreError as exc:
            self._drop_private()
            raise StoreError(f"{self.path}: {exc}") from exc
        except sqlite3.Error as exc:
            self._drop_private()
            hint = (
                "; `cc-daemon recover` saves what can be read"
                if isinstance(exc, sqlite3.DatabaseError)
                and ("malformed" in str(exc) or "not a database" in str(exc))
                else ""
            )
            raise StoreError(f"cannot read {self.path}: {exc}{hint}") from exc
        except OSError as exc:
            self._drop_private()
            raise StoreError(f"cannot read {self.path}: {exc}") from exc
        try:
            self.problems = self._judge(found)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------ opening

    def _open(self, found: files.JournalFiles) -> sqlite3.Connection:
        uri = self.path.resolve().as_uri()
        if not found.wal or found.wal_refused is not None:
            # Nobody has it open (SQLite removes the log with its last connection),
            # or its log is not one to read: read the file alone, making nothing beside it.
            return self._snapshot(f"{uri}?immutable=1")
        if found.odd_companions:
            return self._private_copy()
        try:
            return self._snapshot(f"{uri}?mode=ro")
        except sqlite3.OperationalError as exc:
            code = getattr(exc, "sqlite_errorcode", 0) & 0xFF
            if code not in (_SQLITE_READONLY, _SQLITE_CANTOPEN):
                raise
        return self._private_copy()

    def _use(self, conn: sqlite3.Connection) -> None:
        self._conn = conn
        conn.text_factory = self._decode

    def _connect(self, uri: str) -> sqlite3.Connection:
        conn = sqlite3.connect(uri, uri=True, isolation_level=None)
        self._bounds = guard.Bounds(conn, self._query_s)  # before any statement runs
        return conn

    def _snapshot(self, uri: str) -> sqlite3.Connection:
        """Open `uri` and begin the one read transaction of the reader's life."""
        conn = self._connect(uri)
        try:
            with self._bounds.statement():
                version = schema.file_version(conn)
            if version < schema.SCHEMA_VERSION:
                conn = self._migrated_copy(conn)
            # One read transaction for the reader's life: one snapshot.
            with self._bounds.statement():
                conn.execute("BEGIN")
                conn.execute("SELECT count(*) FROM sqlite_master").fetchone()
        except BaseException:
            conn.close()
            raise
        return conn

    def _private_copy(self) -> sqlite3.Connection:
        """Read a copy of the file and its log (a directory we may not write, so no `-shm`
        can be made; or a `-shm` or `-journal` beside it that is not a file)."""
        wal = Path(f"{self.path}-wal")
        if not wal.exists() or wal.stat().st_size == 0:
            # No log: the file alone is the journal, and nothing is writing it.
            return self._snapshot(f"{self.path.resolve().as_uri()}?immutable=1")
        self._private = scratch.make("read")
        copy = self._private / self.path.name
        for _ in range(_COPY_ATTEMPTS):
            before = self._signature(wal)
            copy.unlink(missing_ok=True)
            Path(f"{copy}-wal").unlink(missing_ok=True)
            files.copy_regular(self.path, copy)
            files.copy_regular(wal, f"{copy}-wal", files.WAL_MAX_BYTES)
            if self._signature(wal) == before:
                break
        # The copy is ours: SQLite may build its -shm beside it and replay the log.
        return self._snapshot(f"{copy.as_uri()}?mode=ro")

    def _signature(self, wal: Path) -> tuple[int, int, bytes]:
        """What changes when the daemon checkpoints: the file, and the log's salt."""
        stat = os.stat(self.path)
        with files.open_regular(wal, files.WAL_MAX_BYTES) as log:
            header = log.read(32)
        return stat.st_size, stat.st_mtime_ns, header

    def _migrated_copy(self, conn: sqlite3.Connection) -> sqlite3.Connection:
        """An older journal migrated in a copy of our own: in memory, or in a private file
        when it is big (a stranger's file may be any size)."""
        target = ":memory:"
        if self.path.stat().st_size > MIGRATE_IN_MEMORY_MAX:
            if self._private is None:
                self._private = scratch.make("read")
            target = str(self._private / f"migrated-{self.path.name}")
        copy = sqlite3.connect(target, isolation_level=None)
        try:
            conn.backup(copy)
            schema.migrate(copy)
        except BaseException:
            copy.close()
            raise
        finally:
            conn.close()
        self._bounds = guard.Bounds(copy, self._query_s)
        return copy

    def _drop_private(self) -> None:
        private, self._private = self._private, None
        if private is not None:
            scratch.remove(private)

    def close(self) -> None:
        self._conn.close()
        self._drop_private()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: object, *exc_info: object) -> None:
        self.close()
        report = self.damage_report() if exc_type is None else None
        if report is not None:  # after the answer: say what it lacks
            raise DamagedJournalError(report)

    # ------------------------------------------------------------ damage

    def _decode(self, raw: bytes) -> str:
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            self._bad_text += 1
            return raw.decode("utf-8", errors="replace")

    def _judge(self, found: files.JournalFiles) -> list[str]:
        """What is wrong with the file; a damaged one is read from a salvaged copy, and
        a table that is not one of the journal's shape is read as an empty one."""
        problems = [found.wal_refused] if found.wal_refused else []
        problems += [f"{odd}: not opened" for odd in found.odd_companions]
        if found.wal and found.wal_refused is None:
            wal = self._cache.wal_damage(self.path)
            if wal is not None:
                problems.append(wal)
        stamp = files.stamp(self.path)
        try:
            damaged = self._cache.quick_check(
                (str(self.path), stamp, found.wal_refused is None),
                lambda: damage.quick_check(self._bounds),
            )
        except guard.QueryTimeout as exc:
            problems.append(f"SQLite's check of the file did not finish ({exc})")
            damaged = []
        except sqlite3.Error as exc:
            damaged = [str(exc)]
        if damaged:
            problems.append(f"SQLite's check found damage: {'; '.join(damaged)}")
            self._read_salvaged(found)
        try:
            problems += guard.check_tables(self._bounds)
        except (sqlite3.Error, guard.QueryTimeout) as exc:
            raise DamagedJournalError(
                f"{self.path} is damaged: cannot read its tables ({exc});"
                " `cc-daemon recover` saves what can be read"
            ) from exc
        return problems

    def _read_salvaged(self, found: files.JournalFiles) -> None:
        """Read what `damage.salvage` can save of the file, from the cache's copy."""
        try:
            conn, salvage = self._cache.open_copy(self.path, (str(self.path), found.key))
        except (sqlite3.Error, OSError, StoreError) as exc:
            raise DamagedJournalError(f"{self.path} is damaged beyond reading: {exc}") from exc
        self._conn.close()
        self._bounds = guard.Bounds(conn, self._query_s)
        self._use(conn)
        with self._bounds.statement():
            conn.execute("BEGIN")
        self.salvage = salvage

    def _shield(self) -> bool:
        """Values too big to load: read NULL in their place, and say so once."""
        found = guard.shield_oversize(self._bounds)
        if not found:
            return False
        count = sum(found.values())
        where = ", ".join(f"{table} {n}" for table, n in found.items())
        size = files.size_text(guard.CELL_MAX_BYTES)
        noun = "value" if count == 1 else "values"
        self.problems.append(f"{count} {noun} over {size} not read ({where})")
        return True

    def _query(self, sql: str, params: Any, what: str) -> list[tuple[Any, ...]]:
        try:
            try:
                return self._bounds.rows(sql, params)
            except sqlite3.DataError as exc:
                if not guard.too_big(exc) or not self._shield():
                    raise
            return self._bounds.rows(sql, params)
        except guard.QueryTimeout as exc:
            raise DamagedJournalError(
                f"{self.path}: reading {what}, {exc}; `cc-daemon recover` saves what can be read"
            ) from exc
        except sqlite3.Error as exc:
            raise DamagedJournalError(
                f"{self.path} is damaged: cannot read {what} ({exc});"
                " `cc-daemon recover` saves what can be read"
            ) from exc

    def _records(
        self, convert: Callable[[tuple[Any, ...]], R | None], rows: list[Any], what: str
    ) -> list[R]:
        found = []
        for row in rows:
            try:
                record = convert(row)
            except (TypeError, ValueError, ArithmeticError):
                self._bad_rows[what] = self._bad_rows.get(what, 0) + 1
                continue
            if record is None:
                continue
            found.append(record)
            json_value = getattr(record, "detail", None) or getattr(record, "plan", None)
            if isinstance(json_value, dict) and records.UNREADABLE_JSON & json_value.keys():
                self._bad_json[what] = self._bad_json.get(what, 0) + 1
        return found

    def damage_report(self) -> str | None:
        """One line saying what this reader could not read, or None if nothing."""
        said = list(self.problems)
        said += [f"{n} unreadable {what} skipped" for what, n in self._bad_rows.items()]
        said += [
            f"{n} {what} with unreadable JSON (given as it is)"
            for what, n in self._bad_json.items()
        ]
        if self._bad_text:
            said.append(f"{self._bad_text} text values not valid UTF-8 (shown with U+FFFD)")
        if not said:
            return None
        return (
            f"{self.path} is damaged: {'; '.join(said)}; the answer lacks what could not be"
            " read (`cc-daemon recover` saves what can be)"
        )

    # ------------------------------------------------------------ reading

    def copy_to(self, target: sqlite3.Connection) -> None:
        """Copy this reader's snapshot, whole, into `target` (SQLite's online backup)."""
        try:
            self._conn.backup(target)
        except sqlite3.DatabaseError as exc:
            raise DamagedJournalError(f"{self.path} is damaged: cannot copy it ({exc})") from exc

    def rows(self, sql: str, what: str, params: Any = ()) -> list[tuple[Any, ...]]:
        """Rows of a statement of the caller's, within the reader's bounds (`snapshot`'s
        counts); DamagedJournalError naming `what` if they cannot be read."""
        return self._query(sql, params, what)

    def casts(self, *, cast_id: int | None = None, since: float | None = None) -> list[CastRecord]:
        """Casts by id; `since` keeps those started at or after that Unix time."""
        where, params = self._filters(
            ("id", cast_id), ("start_wall_s >=", since), ("session_id", self.survey)
        )
        rows = self._query(
            f"SELECT {records.CAST_COLUMNS} FROM casts{where} ORDER BY id", params, "casts"
        )
        return self._records(records.cast, rows, "casts")

    def samples(
        self, *, cast_id: int | None = None, since: float | None = None
    ) -> list[SampleRecord]:
        """Samples by cast, in time order, with their station's position."""
        where, params = self._filters(
            ("s.cast_id", cast_id), ("s.wall_s >=", since), ("c.session_id", self.survey)
        )
        rows = self._query(
            "SELECT s.cast_id, s.mono_s, s.wall_s, s.clock_synced, s.depth_m, s.phase,"
            f" c.lat_e7, c.lon_e7 FROM samples s LEFT JOIN casts c ON c.id = s.cast_id{where}"
            " ORDER BY s.cast_id, s.mono_s, s.id",
            params,
            "samples",
        )
        return self._records(records.sample, rows, "samples")

    def fixes(self, *, cast_id: int | None = None, since: float | None = None) -> list[FixRecord]:
        """Fixes in the order received; with `cast_id`, those received during that cast."""
        clauses: list[str] = []
        params: list[object] = []
        if cast_id is not None:
            found = self.casts(cast_id=cast_id)
            if not found:
                return []
            cast = found[0]
            end_mono, end_wall = self._cast_end(cast)
            if cast.session_id is not None:
                # Monotonic time is exact within a session, even if the wall clock jumped.
                clauses.append("session_id = ? AND mono_s BETWEEN ? AND ?")
                params += [cast.session_id, cast.start_mono_s, end_mono]
            else:
                clauses.append("wall_s BETWEEN ? AND ?")
                params += [cast.start_wall_s, end_wall]
        if since is not None:
            clauses.append("wall_s >= ?")
            params.append(since)
        if self.survey is not None:
            clauses.append("session_id = ?")
            params.append(self.survey)
        where = f" WHERE {' AND '.join(clauses)}" if clauses else ""
        rows = self._query(
            f"SELECT {records.FIX_COLUMNS} FROM fixes{where} ORDER BY id", params, "fixes"
        )
        orders = self._session_orders()
        return self._records(lambda row: records.fix(row, orders), rows, "fixes")

    def fix_batches(self, size: int = 500) -> Iterator[list[FixRecord]]:
        """`fixes()` of the reader's survey, in order, `size` at a time: a ten-day survey
        (864,000 fixes) streamed in bounded memory, by id."""
        orders = self._session_orders()
        after = -(2**63)  # below any rowid
        # `+session_id`: walk the rowids from `after`, not the session's index whole.
        where = "id > ?" + ("" if self.survey is None else " AND +session_id = ?")
        survey = [] if self.survey is None else [self.survey]
        while True:
            rows = self._query(
                f"SELECT id, {records.FIX_COLUMNS} FROM fixes WHERE {where} ORDER BY id LIMIT ?",
                [after, *survey, size],
                "fixes",
            )
            if not rows:
                return
            after = rows[-1][0]
            yield self._records(lambda row: records.fix(row[1:], orders), rows, "fixes")

    def _session_orders(self) -> dict[int | None, str]:
        """Each session's last byte order: "big" until the daemon learnt the order, then
        the one it learnt, so the frames before that are re-decoded with it."""
        rows = self._query(
            "SELECT session_id, ap_time_order, max(id) FROM fixes"
            " WHERE ap_time_order IS NOT NULL AND session_id IS NOT NULL GROUP BY session_id",
            (),
            "fixes",
        )
        return {session: order for session, order, _ in rows if isinstance(order, str)}

    def events(self, *, since: float | None = None) -> list[EventRecord]:
        where, params = self._filters(("wall_s >=", since), ("session_id", self.survey))
        rows = self._query(
            f"SELECT {records.EVENT_COLUMNS} FROM events{where} ORDER BY id", params, "events"
        )
        return self._records(records.event, rows, "events")

    def sonde_samples(
        self, *, cast_id: int | None = None, since: float | None = None
    ) -> list[sonde.SondeSampleRecord]:
        """The sonde's readings in time order (`store.sonde`)."""
        sql, params = sonde.query(cast_id=cast_id, since=since, session=self.survey)
        rows = self._query(sql, params, "the sonde's samples")
        return self._records(sonde.record, rows, "sonde samples")

    def surveys(self) -> list[SurveyRecord]:
        """Every survey in the file (`store.surveys`), whatever `survey` is set to, its
        stations counted as `store.stations` counts them."""
        rows = self._query(surveys.QUERY, (), "the surveys")
        found = self._records(surveys.record, rows, "surveys")
        places, plans = stationrows.places_and_plans(self, None)
        return [surveys.counted(s, places.get(s.id, []), plans.get(s.id)) for s in found]

    def stations(self) -> list[station_rules.Station]:
        """The stations of the reader's survey (`store.stations`); of every survey, one
        after the other, when it reads them all."""
        places, plans = stationrows.places_and_plans(self, self.survey)
        return [
            station
            for session in sorted(places.keys() | plans.keys(), key=lambda k: (k is None, k or 0))
            for station in station_rules.stations(places.get(session, []), plans.get(session))
        ]

    def select_survey(self, choice: str | int) -> SurveyRecord | None:
        """Read only the survey `choice` names (`latest`, a number, or `all`: None).
        StoreError if there is no such survey."""
        chosen = choose_survey(self.surveys(), choice, self.path)
        self.survey = None if chosen is None else chosen.id
        return chosen

    def sonar_readings(
        self, *, since: float | None = None, until: float | None = None, session: int | None = None
    ) -> list[sonar.SonarReadingRecord]:
        """The daemon's own sonar readings in time order (`store.sonar`); `session`: only
        that daemon run's."""
        sql, params = sonar.query(since=since, until=until, session=session)
        rows = self._query(sql, params, "the sonar's readings")
        return self._records(sonar.record, rows, "sonar readings")

    def _cast_end(self, cast: CastRecord) -> tuple[float, float]:
        """When a cast's data ends: its end row, else its last sample, else its start."""
        if cast.end_mono_s is not None and cast.end_wall_s is not None:
            return cast.end_mono_s, cast.end_wall_s
        last = self._query(
            "SELECT max(mono_s), max(wall_s) FROM samples WHERE cast_id = ?", (cast.id,), "samples"
        )[0]
        if not all(isinstance(t, int | float) for t in last):
            return cast.start_mono_s, cast.start_wall_s
        return float(last[0]), float(last[1])

    @staticmethod
    def _filters(*pairs: tuple[str, object]) -> tuple[str, list[object]]:
        clauses: list[str] = []
        params: list[object] = []
        for column, value in pairs:
            if value is not None:
                clauses.append(
                    f"{column} ?" if column.endswith(("=", "<", ">")) else f"{column} = ?"
                )
                params.append(value)
        return (f" WHERE {' AND '.join(clauses)}" if clauses else ""), params
