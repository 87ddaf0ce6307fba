"""The journal's read side: casts, samples, fixes and events as records in SI units.

This module owns opening a journal file for the `casts`, `export` and `plot`
commands and the queries that turn its rows into records in degrees, metres
and seconds. It must never write to the file: it opens it read-only (SQLite
`mode=ro`), so it can run beside the daemon (WAL lets one writer and readers
work at once) and never marks a running cast `unfinished` (only the daemon's
`Journal.open()` may decide that a cast was left by a crash). A file from an
older cc-daemon is migrated in a private in-memory copy, never in place.

A journal with no write-ahead log beside it is one nobody has open (SQLite
removes `-wal` and `-shm` with the last connection): the reader opens it
`immutable`, which reads the file alone and creates nothing beside it, so a
data command leaves no `-wal`/`-shm` behind and needs no write access to the
directory. That is safe because a daemon that starts meanwhile writes to its
new log, not to the file, until a checkpoint (4 MB of log, or its close). With
a log present (the daemon running, or killed) the reader opens it `mode=ro`,
using the `-shm` that is there; if it cannot (a directory it may not write),
it reads a private copy of the file and its log in a temporary directory.

All the reads of one `JournalReader` see one snapshot of the file, so a cast
and its samples agree even while the daemon is writing.
"""

import json
import os
import shutil
import sqlite3
import tempfile
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, Self, TypeVar

from cc_daemon.store import schema, sonar, sonde
from cc_daemon.store.schema import StoreError
from cc_daemon.store.surveys import SurveyRecord, choose_survey, list_surveys

if TYPE_CHECKING:
    from cc_daemon.store.damage import Salvage

R = TypeVar("R")


_UNREADABLE_JSON = frozenset({"unreadable_detail", "unreadable_plan"})


class DamagedJournalError(StoreError):
    """The journal is damaged: what could not be read, in one line."""


# SQLite's primary result codes for "may not write here" and "cannot open".
_SQLITE_READONLY = 8
_SQLITE_CANTOPEN = 14
# Copying a file the daemon checkpoints at that moment can give a mismatched
# pair (file, log): copy again, this many times at most.
_COPY_ATTEMPTS = 5


class CastRecord(NamedTuple):
    id: int
    session_id: int | None
    start_mono_s: float
    start_wall_s: float
    start_clock_synced: bool
    ap_timestamp_s: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    water_depth_m: float  # the sonar distance in the cast's `M` frame
    sonar_confidence_pct: int
    planned_depth_m: float
    mode: str
    plan: dict[str, Any]
    end_mono_s: float | None
    end_wall_s: float | None
    outcome: str | None  # None while the cast runs (or until the daemon reopens the file)
    reached_depth_m: float | None
    reason: str | None
    samples: int
    winch_backend: str | None = None  # "sim", "gpio", "gpio-mock"; None: not recorded
    simulated: bool | None = None  # True: no probe moved (a simulated winch)


class SampleRecord(NamedTuple):
    cast_id: int
    mono_s: float
    wall_s: float
    clock_synced: bool
    depth_m: float
    phase: str
    lat_deg: float | None  # the station's position: the boat holds it during the cast
    lon_deg: float | None


class FixRecord(NamedTuple):
    session_id: int | None
    mono_s: float
    wall_s: float
    clock_synced: bool
    frame: str
    ap_timestamp_s: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    sonar_distance_m: float
    sonar_confidence_pct: int
    # The autopilot's clock, decoded in the byte order its session settled on (the
    # first frames re-decoded once the order was learnt); None before journal v6.
    ap_time_s: int | None = None
    ap_time_order: str | None = None


class EventRecord(NamedTuple):
    session_id: int | None
    mono_s: float
    wall_s: float
    clock_synced: bool
    kind: str
    detail: dict[str, Any]


def iso_utc(wall_s: float | None) -> str:
    """Unix seconds as ISO 8601 UTC with milliseconds and a `Z`; '' for None."""
    if wall_s is None:
        return ""
    stamp = datetime.fromtimestamp(wall_s, tz=UTC).isoformat(timespec="milliseconds")
    return stamp.replace("+00:00", "Z")


def parse_time(text: str) -> float:
    """ISO 8601 (`2024-05-01`, `2024-05-01T10:00Z`, with an offset) as Unix seconds.

    A time without an offset is taken as UTC, like every time in the journal.
    """
    stamp = datetime.fromisoformat(text.strip())
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=UTC)
    return stamp.timestamp()


_CAST_COLUMNS = (
    "id, session_id, start_mono_s, start_wall_s, start_clock_synced, ap_timestamp_s,"
    " lat_e7, lon_e7, alt_mm, sonar_distance_mm, sonar_confidence_pct, planned_depth_m, mode,"
    " plan_json, end_mono_s, end_wall_s, outcome, reached_depth_m, reason,"
    " (SELECT count(*) FROM samples WHERE cast_id = casts.id), winch_backend, simulated"
)
_FIX_COLUMNS = (
    "session_id, mono_s, wall_s, clock_synced, frame, ap_timestamp_s, lat_e7, lon_e7, alt_mm,"
    " sonar_distance_mm, sonar_confidence_pct, ap_time_s, ap_time_order"
)


def _cast(row: tuple[Any, ...]) -> CastRecord:
    try:
        plan = json.loads(_plain(row[13]))
    except (ValueError, TypeError):
        plan = {"unreadable_plan": repr(row[13])}
    return CastRecord(
        id=row[0],
        session_id=row[1],
        start_mono_s=row[2],
        start_wall_s=row[3],
        start_clock_synced=bool(row[4]),
        ap_timestamp_s=row[5],
        lat_deg=row[6] / 1e7,
        lon_deg=row[7] / 1e7,
        alt_m=row[8] / 1000.0,
        water_depth_m=row[9] / 1000.0,
        sonar_confidence_pct=row[10],
        planned_depth_m=row[11],
        mode=row[12],
        plan=plan if isinstance(plan, dict) else {"plan": plan},
        end_mono_s=row[14],
        end_wall_s=row[15],
        outcome=row[16],
        reached_depth_m=row[17],
        reason=row[18],
        samples=row[19],
        winch_backend=row[20],
        simulated=None if row[21] is None else bool(row[21]),
    )


def _plain(value: Any) -> Any:
    """A JSON value as stored: text, or bytes where text belongs (a damaged file)."""
    if isinstance(value, bytes):
        return value.decode("utf-8")  # UnicodeDecodeError: a ValueError, the row is skipped
    return value


def _event(r: tuple[Any, ...]) -> EventRecord:
    try:
        detail = json.loads(_plain(r[5]))
    except (ValueError, TypeError):
        detail = {"unreadable_detail": repr(r[5])}
    if not isinstance(r[4], str):
        raise TypeError(f"event kind {r[4]!r}")
    return EventRecord(r[0], float(r[1]), float(r[2]), bool(r[3]), r[4], detail)


def _sample(r: tuple[Any, ...]) -> SampleRecord:
    if not isinstance(r[5], str):
        raise TypeError(f"phase {r[5]!r}")
    return SampleRecord(
        cast_id=int(r[0]),
        mono_s=float(r[1]),
        wall_s=float(r[2]),
        clock_synced=bool(r[3]),
        depth_m=float(r[4]),
        phase=r[5],
        lat_deg=None if r[6] is None else r[6] / 1e7,
        lon_deg=None if r[7] is None else r[7] / 1e7,
    )


def _decoded(raw: int, order: str | None, stored: int | None) -> int | None:
    """The timestamp's two bytes (stored read big-endian) in the session's byte order."""
    if order == "little":
        return ((raw & 0xFF) << 8) | (raw >> 8)
    if order == "big":
        return raw
    return stored


def _fix(row: tuple[Any, ...], orders: dict[int | None, str]) -> FixRecord:
    order = orders.get(row[0], row[12])
    return FixRecord(
        session_id=row[0],
        mono_s=row[1],
        wall_s=row[2],
        clock_synced=bool(row[3]),
        frame=row[4],
        ap_timestamp_s=row[5],
        lat_deg=row[6] / 1e7,
        lon_deg=row[7] / 1e7,
        alt_m=row[8] / 1000.0,
        sonar_distance_m=row[9] / 1000.0,
        sonar_confidence_pct=row[10],
        ap_time_s=_decoded(row[5], order, row[11]),
        ap_time_order=order,
    )


class JournalReader:
    """A read-only, consistent view of one journal file. Use as a context manager."""

    def __init__(self, path: Path, *, survey: int | None = None) -> None:
        """`survey`: read only that survey's rows (a session's id; None: every row)."""
        self.path = Path(path)
        self.survey = survey
        if not self.path.is_file():
            raise StoreError(f"no journal at {self.path}")
        self._private: tempfile.TemporaryDirectory[str] | None = None
        uri = self.path.resolve().as_uri()
        try:
            try:
                if not os.path.lexists(f"{self.path}-wal"):
                    # Nobody has it open (SQLite removes the log with its last
                    # connection): read the file alone, making nothing beside it.
                    conn = self._snapshot(f"{uri}?immutable=1")
                else:
                    conn = self._snapshot(f"{uri}?mode=ro")
            except sqlite3.OperationalError as exc:
                code = getattr(exc, "sqlite_errorcode", 0) & 0xFF
                if code not in (_SQLITE_READONLY, _SQLITE_CANTOPEN):
                    raise
                conn = self._snapshot_without_writing_beside()
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
        self._conn = conn
        self._bad_text = 0
        self._bad_rows: dict[str, int] = {}
        self._bad_json: dict[str, int] = {}
        conn.text_factory = self._decode
        self.salvage: Salvage | None = None  # set when read from a salvaged copy
        try:
            self.problems = self._judge()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------ damage

    def _decode(self, raw: bytes) -> str:
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            self._bad_text += 1
            return raw.decode("utf-8", errors="replace")

    def _judge(self) -> list[str]:
        """What is wrong with the file; a damaged one is read from a salvaged copy."""
        from cc_daemon.store import damage  # the daemon imports this module, never needs that

        problems: list[str] = []
        wal = damage.wal_damage(self.path)
        if wal is not None:
            problems.append(wal)
        try:
            found = damage.quick_check(self._conn)
        except sqlite3.Error as exc:
            found = [str(exc)]
        if found:
            problems.append(f"SQLite's check found damage: {'; '.join(found)}")
            self._read_salvaged()
        present = {n for (n,) in self._query("SELECT name FROM sqlite_master", (), "the schema")}
        missing = [t for t in damage.journal_tables() if t not in present]
        if missing:
            problems.append(f"tables missing: {', '.join(missing)}")
        return problems

    def _read_salvaged(self) -> None:
        """Read what `damage.salvage` can save of the file, from a private copy."""
        if self._private is None:
            self._private = tempfile.TemporaryDirectory(prefix="cc-daemon-read-")
        from cc_daemon.store import damage

        copy = Path(self._private.name) / f"salvaged-{self.path.name}"
        try:
            salvage = damage.salvage(self.path, copy)
        except (sqlite3.Error, OSError) as exc:
            raise DamagedJournalError(f"{self.path} is damaged beyond reading: {exc}") from exc
        self._conn.close()
        self._conn = sqlite3.connect(f"{copy.as_uri()}?mode=ro", uri=True, isolation_level=None)
        self._conn.text_factory = self._decode
        self._conn.execute("BEGIN")
        self.salvage = salvage

    def _query(self, sql: str, params: Any, what: str) -> list[tuple[Any, ...]]:
        try:
            return self._conn.execute(sql, params).fetchall()
        except sqlite3.Error as exc:
            raise DamagedJournalError(
                f"{self.path} is damaged: cannot read {what} ({exc});"
                " `cc-daemon recover` saves what can be read"
            ) from exc

    def _records(
        self, convert: Callable[[tuple[Any, ...]], R], rows: list[Any], what: str
    ) -> list[R]:
        records = []
        for row in rows:
            try:
                record = convert(row)
            except (TypeError, ValueError, ArithmeticError):
                self._bad_rows[what] = self._bad_rows.get(what, 0) + 1
                continue
            records.append(record)
            json_value = getattr(record, "detail", None) or getattr(record, "plan", None)
            if isinstance(json_value, dict) and _UNREADABLE_JSON & json_value.keys():
                self._bad_json[what] = self._bad_json.get(what, 0) + 1
        return records

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

    def _snapshot(self, uri: str) -> sqlite3.Connection:
        """Open `uri` and begin the one read transaction of the reader's life."""
        conn = sqlite3.connect(uri, uri=True, isolation_level=None)
        try:
            version = schema.file_version(conn)
            if version < schema.SCHEMA_VERSION:
                conn = self._migrated_copy(conn)
            # One read transaction for the reader's life: one snapshot.
            conn.execute("BEGIN")
            conn.execute("SELECT count(*) FROM casts").fetchone()
        except BaseException:
            conn.close()
            raise
        return conn

    def _snapshot_without_writing_beside(self) -> sqlite3.Connection:
        """Read a file whose directory we may not write (so no `-shm` can be made)."""
        wal = Path(f"{self.path}-wal")
        if not wal.exists() or wal.stat().st_size == 0:
            # No log: the file alone is the journal, and nothing is writing it.
            return self._snapshot(f"{self.path.resolve().as_uri()}?immutable=1")
        self._private = tempfile.TemporaryDirectory(prefix="cc-daemon-read-")
        copy = Path(self._private.name) / self.path.name
        for _ in range(_COPY_ATTEMPTS):
            before = self._signature(wal)
            shutil.copyfile(self.path, copy)
            shutil.copyfile(wal, f"{copy}-wal")
            if self._signature(wal) == before:
                break
        # The copy is ours: SQLite may build its -shm beside it and replay the log.
        return self._snapshot(f"{copy.as_uri()}?mode=ro")

    def _signature(self, wal: Path) -> tuple[int, int, bytes]:
        """What changes when the daemon checkpoints: the file, and the log's salt."""
        stat = os.stat(self.path)
        with wal.open("rb") as log:
            header = log.read(32)
        return stat.st_size, stat.st_mtime_ns, header

    def _drop_private(self) -> None:
        private, self._private = self._private, None
        if private is not None:
            private.cleanup()

    @staticmethod
    def _migrated_copy(conn: sqlite3.Connection) -> sqlite3.Connection:
        copy = sqlite3.connect(":memory:", isolation_level=None)
        try:
            conn.backup(copy)
            schema.migrate(copy)
        except BaseException:
            copy.close()
            raise
        finally:
            conn.close()
        return copy

    def close(self) -> None:
        self._conn.close()
        self._drop_private()

    def copy_to(self, target: sqlite3.Connection) -> None:
        """Copy this reader's snapshot, whole, into `target` (SQLite's online backup)."""
        try:
            self._conn.backup(target)
        except sqlite3.DatabaseError as exc:
            raise DamagedJournalError(f"{self.path} is damaged: cannot copy it ({exc})") from exc

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: object, *exc_info: object) -> None:
        self.close()
        report = self.damage_report() if exc_type is None else None
        if report is not None:  # after the answer: say what it lacks
            raise DamagedJournalError(report)

    def casts(self, *, cast_id: int | None = None, since: float | None = None) -> list[CastRecord]:
        """Casts by id; `since` keeps those started at or after that Unix time."""
        where, params = self._filters(
            ("id", cast_id), ("start_wall_s >=", since), ("session_id", self.survey)
        )
        rows = self._query(f"SELECT {_CAST_COLUMNS} FROM casts{where} ORDER BY id", params, "casts")
        return self._records(_cast, rows, "casts")

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
        return self._records(_sample, rows, "samples")

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
        rows = self._query(f"SELECT {_FIX_COLUMNS} FROM fixes{where} ORDER BY id", params, "fixes")
        orders = self._session_orders()
        return self._records(lambda row: _fix(row, orders), rows, "fixes")

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
            "SELECT session_id, mono_s, wall_s, clock_synced, kind, detail_json"
            f" FROM events{where} ORDER BY id",
            params,
            "events",
        )
        return self._records(_event, rows, "events")

    def sonde_samples(
        self, *, cast_id: int | None = None, since: float | None = None
    ) -> list[sonde.SondeSampleRecord]:
        """The sonde's readings in time order (`store.sonde`)."""
        try:
            return sonde.read_samples(self._conn, cast_id=cast_id, since=since, session=self.survey)
        except sqlite3.Error as exc:
            raise DamagedJournalError(
                f"{self.path} is damaged: cannot read the sonde's samples ({exc})"
            ) from exc
        except (TypeError, ValueError, ArithmeticError) as exc:
            raise DamagedJournalError(
                f"{self.path} is damaged: an unreadable sonde sample ({exc})"
            ) from exc

    def surveys(self) -> list[SurveyRecord]:
        """Every survey in the file (`store.surveys`), whatever `survey` is set to."""
        return list_surveys(self._conn)

    def select_survey(self, choice: str | int) -> SurveyRecord | None:
        """Read only the survey `choice` names (`latest`, a number, or `all`: None).
        StoreError if there is no such survey."""
        chosen = choose_survey(self.surveys(), choice, self.path)
        self.survey = None if chosen is None else chosen.id
        return chosen

    def sonar_readings(
        self, *, since: float | None = None, until: float | None = None
    ) -> list[sonar.SonarReadingRecord]:
        """The daemon's own sonar readings in time order (`store.sonar`)."""
        try:
            return sonar.read_readings(self._conn, since=since, until=until)
        except sqlite3.Error as exc:
            raise DamagedJournalError(
                f"{self.path} is damaged: cannot read the sonar's readings ({exc})"
            ) from exc

    def _cast_end(self, cast: CastRecord) -> tuple[float, float]:
        """When a cast's data ends: its end row, else its last sample, else its start."""
        if cast.end_mono_s is not None and cast.end_wall_s is not None:
            return cast.end_mono_s, cast.end_wall_s
        last = self._query(
            "SELECT max(mono_s), max(wall_s) FROM samples WHERE cast_id = ?", (cast.id,), "samples"
        )[0]
        if last[0] is None:
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
