"""A journal file from someone else, read within bounds: time, the size of a value, the tables.

A journal copied off another boat, a USB stick or a stranger's laptop is a
program SQLite runs: a table replaced by a view runs the view's query (an endless
recursive one, or a 12-way self-join, never ends), and one cell can hold
hundreds of megabytes. This module owns the bounds every connection of the read
side (the data commands, the field page, `snapshot`, `recover`) puts on such a
file:

- **time**: a progress handler ends any statement that runs past its deadline,
  and `Bounds.rows` turns that into `QueryTimeout`, one line;
- **a value's size**: SQLite's length limit is set to `CELL_MAX_BYTES`, so a
  bigger value is never loaded (the statement fails with "string or blob too
  big"); `shield_oversize` then finds those cells and puts a TEMP view in front
  of the table that gives NULL in their place;
- **the tables' shape**: every journal table must be a real table with the
  journal's columns; one that is missing or is not (a view, a virtual table, a
  table without its columns, with generated columns or without row ids) is
  shadowed by an empty TEMP table of the journal's shape, so no statement ever
  runs what the file holds in its place (`check_tables`).

It never writes the file: TEMP tables and views live in the connection's own
temporary database, and SQLite looks names up there first.
"""

from __future__ import annotations

import contextlib
import functools
import math
import sqlite3
import time
from collections.abc import Iterator
from typing import Any, NamedTuple

from cc_daemon.store import schema
from cc_daemon.store.schema import StoreError

CELL_MAX_BYTES = 1 << 20  # the journal's biggest value (a cast's plan) is under 1 KiB
# The longest statement of a real journal, all 864,960 fixes of a 10-day survey (71 MB):
# 5.6 s on the development machine at a load average of 26 on its 2 cores.
QUERY_S = 60.0
_TICK = 10_000  # SQLite's virtual-machine steps between two looks at the clock
_SQLITE_INTERRUPT = 9
_SQLITE_TOOBIG = 18


class QueryTimeout(StoreError):
    """A statement ran past its time bound and was ended."""


class Table(NamedTuple):
    columns: tuple[str, ...]
    create: str  # the journal's CREATE TABLE statement, columns added by migrations included


@functools.cache
def layout() -> dict[str, Table]:
    """The journal's tables, in the order they were made, as a current file has them."""
    with contextlib.closing(sqlite3.connect(":memory:", isolation_level=None)) as conn:
        schema.migrate(conn)
        rows = conn.execute(
            "SELECT name, sql FROM sqlite_master WHERE type = 'table'"
            " AND name NOT LIKE 'sqlite%' ORDER BY rowid"
        ).fetchall()
        return {
            str(name): Table(
                tuple(str(c[1]) for c in conn.execute(f"PRAGMA table_info({name})")), str(sql)
            )
            for name, sql in rows
        }


def quoted(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


def too_big(exc: sqlite3.Error) -> bool:
    return (getattr(exc, "sqlite_errorcode", 0) & 0xFF) == _SQLITE_TOOBIG


class Bounds:
    """The bounds on one connection: its values' size, and each statement's time."""

    def __init__(self, conn: sqlite3.Connection, seconds: float | None = None) -> None:
        self.conn = conn
        self.seconds = QUERY_S if seconds is None else seconds
        # An overall deadline (a salvage's), applied to every statement run meanwhile.
        self.until = math.inf
        self._statement = math.inf
        conn.setlimit(sqlite3.SQLITE_LIMIT_LENGTH, CELL_MAX_BYTES)
        conn.set_progress_handler(self._late, _TICK)

    def _late(self) -> bool:
        return time.monotonic() > min(self._statement, self.until)

    @contextlib.contextmanager
    def statement(self) -> Iterator[None]:
        """Bound what runs in the block to `seconds`; QueryTimeout when it runs out."""
        self._statement = time.monotonic() + self.seconds
        try:
            yield
        except sqlite3.OperationalError as exc:
            if (getattr(exc, "sqlite_errorcode", 0) & 0xFF) != _SQLITE_INTERRUPT:
                raise
            if time.monotonic() > self.until:
                raise QueryTimeout("a query ran past the deadline and was ended") from exc
            raise QueryTimeout(f"a query ran past {self.seconds} s and was ended") from exc
        finally:
            self._statement = math.inf

    def rows(self, sql: str, params: Any = ()) -> list[tuple[Any, ...]]:
        with self.statement():
            return self.conn.execute(sql, params).fetchall()


def _shape(bounds: Bounds, name: str, table: Table, db: str) -> str | None:
    """None if `db.name` is a real table with the journal's columns; else why not."""
    found = bounds.rows(
        f"SELECT type, sql FROM {db}.sqlite_master"
        " WHERE name = ? COLLATE NOCASE AND type != 'trigger'",
        (name,),
    )
    if not found:
        return "missing"
    kind, sql = found[0]
    if kind != "table":
        return f"{'an' if str(kind)[:1] in 'aeiou' else 'a'} {kind}, not a table"
    if str(sql or "").lstrip().upper().startswith("CREATE VIRTUAL"):
        return "a virtual table"
    info = bounds.rows(f"PRAGMA {db}.table_xinfo({quoted(name)})")
    if any(row[6] for row in info):  # hidden: generated columns run an expression per read
        return "a table with generated columns"
    have = {str(row[1]) for row in info}
    lacking = [c for c in table.columns if c not in have]
    if lacking:
        return f"a table without the columns {', '.join(lacking)}"
    try:
        bounds.rows(f"SELECT rowid FROM {db}.{quoted(name)} LIMIT 0")
    except sqlite3.OperationalError:
        return "a table without row ids"
    return None


def unsound(bounds: Bounds, db: str = "main") -> dict[str, str]:
    """The journal tables of `db` that must not be read, and why."""
    out = {}
    for name, table in layout().items():
        why = _shape(bounds, name, table, db)
        if why is not None:
            out[name] = why
    return out


def check_tables(bounds: Bounds) -> list[str]:
    """Shadow every journal table that is not sound by an empty one; say which, once."""
    bad = unsound(bounds)
    with bounds.statement():
        for name in bad:
            create = layout()[name].create
            bounds.conn.execute("CREATE TEMP TABLE " + create.split("TABLE", 1)[1])
    missing = [name for name, why in bad.items() if why == "missing"]
    said = [f"tables missing: {', '.join(missing)}"] if missing else []
    said += [f"{name} is {why}: not read" for name, why in bad.items() if why != "missing"]
    return said


def _huge_columns(bounds: Bounds, table: str, columns: tuple[str, ...], rowid: int) -> list[str]:
    found = []
    for column in columns:
        try:
            (length,) = bounds.rows(
                f"SELECT length({quoted(column)}) FROM main.{quoted(table)} WHERE rowid = ?",
                (rowid,),
            )[0]
        except sqlite3.DataError as exc:
            if not too_big(exc):
                raise
            found.append(column)
            continue
        if isinstance(length, int) and length > CELL_MAX_BYTES:  # a blob: never loaded
            found.append(column)
    return found


def oversize_cells(bounds: Bounds, table: str) -> dict[str, list[int]]:
    """The row ids of `table`'s values over CELL_MAX_BYTES, by column; none is loaded."""
    columns = layout()[table].columns
    lengths = ", ".join(f"length({quoted(c)})" for c in columns)
    scan = f"SELECT rowid, {lengths} FROM main.{quoted(table)} WHERE rowid > ? ORDER BY rowid"
    found: dict[str, list[int]] = {}
    last = -(1 << 63)
    with bounds.statement():
        while True:
            try:
                for row in bounds.conn.execute(scan, (last,)):
                    last = row[0]
                    for column, length in zip(columns, row[1:], strict=True):
                        if isinstance(length, int) and length > CELL_MAX_BYTES:
                            found.setdefault(column, []).append(last)
                return found
            except sqlite3.DataError as exc:
                if not too_big(exc):
                    raise
            # The row after the last one read holds a value too big to load.
            after = bounds.conn.execute(
                f"SELECT rowid FROM main.{quoted(table)} WHERE rowid > ? ORDER BY rowid LIMIT 1",
                (last,),
            ).fetchone()
            if after is None:
                return found
            last = after[0]
            for column in _huge_columns(bounds, table, columns, last):
                if last not in found.get(column, []):
                    found.setdefault(column, []).append(last)


def shield_oversize(bounds: Bounds) -> dict[str, int]:
    """Put a TEMP view giving NULL for every value over CELL_MAX_BYTES in front of each
    sound journal table holding one; returns how many values, by table."""
    shadowed = {str(n) for (n,) in bounds.rows("SELECT name FROM temp.sqlite_master")}
    counts: dict[str, int] = {}
    for table, shape in layout().items():
        if table in shadowed:
            continue
        cells = oversize_cells(bounds, table)
        if not cells:
            continue
        picks = []
        for column in shape.columns:
            ids = cells.get(column)
            name = quoted(column)
            if ids is None:
                picks.append(name)
            else:
                listed = ", ".join(str(int(i)) for i in ids)
                picks.append(
                    f"CASE WHEN main.{quoted(table)}.rowid IN ({listed}) THEN NULL"
                    f" ELSE {name} END AS {name}"
                )
        with bounds.statement():
            bounds.conn.execute(
                f"CREATE TEMP VIEW {quoted(table)} AS SELECT {', '.join(picks)}"
                f" FROM main.{quoted(table)}"
            )
        counts[table] = sum(len(ids) for ids in cells.values())
    return counts
