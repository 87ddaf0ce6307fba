"""Damaged journals: finding the damage, and saving every row that can be read.

This module owns judging a journal file (SQLite's `quick_check`; the log's
frames are `store.walcheck`'s) and salvaging one into a new journal: SQLite's
own `.recover` through the `sqlite3` program where there is one
(`store.recover_shell`), else row by row, in blocks of row ids, skipping what
cannot be read. Every statement on the damaged file is bounded
(`store.guard`): by the salvage's time, by the size of a value, and never on a
table that is not one (a view put in its place). It never writes the damaged
file nor anything beside it, nor a new journal through a symlink.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cc_daemon.store import files, guard, schema, scratch
from cc_daemon.store.recover_shell import read_uri, recover_with_cli
from cc_daemon.store.walcheck import wal_damage

__all__ = ["CHECK_LIMIT", "SALVAGE_S", "Salvage", "quick_check", "salvage", "wal_damage"]

# `quick_check` messages kept: enough to name the damage, few enough for a line.
CHECK_LIMIT = 5
_BLOCK = 256  # row ids read at once while salvaging row by row
_MAX_PROBES = 4096  # row ids tried one by one after a bad stretch
_MAX_SKIPS = 48  # doubling steps past a bad stretch before giving up on a table
SALVAGE_S = 120.0  # a salvage's time for all tables together
_MAX_PAD_BYTES = 4 << 30  # a header claiming more is itself damaged


def quick_check(bounds: guard.Bounds) -> list[str]:
    """SQLite's `quick_check` of the open file, within the connection's time bound:
    [] when it is sound."""
    rows = bounds.rows(f"PRAGMA quick_check({CHECK_LIMIT})")
    found = [
        line.strip()
        for row in rows
        for line in str(row[0]).splitlines()
        if line.strip() and not line.startswith("*** in database")
    ]
    return [] if found == ["ok"] else found


@dataclass
class Salvage:
    """What `salvage` saved, table by table, and what it could not."""

    method: str  # "sqlite3 .recover" or "row by row"
    rows: dict[str, int] = field(default_factory=dict)  # saved, by table
    source_rows: dict[str, int | None] = field(default_factory=dict)  # counted, if it could be
    lost_and_found: int = 0  # rows .recover found but could not place in a table
    problems: list[str] = field(default_factory=list)
    note: str = ""  # why .recover was not used


def journal_tables() -> list[str]:
    """The tables of a current journal, in the order they were made."""
    return list(guard.layout())


def _new_journal(dest: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(dest, isolation_level=None)
    conn.execute(f"PRAGMA application_id = {schema.APPLICATION_ID}")
    schema.migrate(conn)
    return conn


def _columns(conn: sqlite3.Connection, table: str, db: str = "main") -> list[str]:
    return [str(row[1]) for row in conn.execute(f"PRAGMA {db}.table_info({table})")]


def _count(conn: sqlite3.Connection, table: str) -> int | None:
    try:
        return int(conn.execute(f"SELECT count(*) FROM {table}").fetchone()[0])
    except sqlite3.Error:
        return None


def _read_from(
    src: sqlite3.Connection, table: str, names: str, after: int
) -> tuple[list[tuple[Any, ...]], bool]:
    """Rows of `table` with row ids above `after`, a block at most, until one fails to read;
    and whether the read went through."""
    got: list[tuple[Any, ...]] = []
    try:
        cursor = src.execute(
            f"SELECT rowid, {names} FROM {table} WHERE rowid > ? ORDER BY rowid LIMIT {_BLOCK}",
            (after,),
        )
        for row in cursor:
            got.append(row)
    except sqlite3.Error:
        return got, False
    return got, True


def _probe(src: sqlite3.Connection, table: str, names: str, low: int, high: int) -> list[Any]:
    """Rows with row ids in (low, high], one at a time (a bad page in between)."""
    found: list[Any] = []
    for rowid in range(low + 1, min(high, low + _MAX_PROBES) + 1):
        with contextlib.suppress(sqlite3.Error):
            found += src.execute(
                f"SELECT rowid, {names} FROM {table} WHERE rowid = ?", (rowid,)
            ).fetchall()
    return found


def _copy_by_blocks(
    src: sqlite3.Connection,
    dest: sqlite3.Connection,
    table: str,
    columns: list[str],
    deadline: float,
    source: str | None = None,
) -> tuple[int, int]:
    """Copy what can be read of `table` (from `source`, another name for it, if given) in
    row id order, stepping over what cannot.

    Returns (rows copied, unreadable stretches met). Past a bad page the next
    readable row id is searched for by doubling steps, then the stretch skipped
    is probed row by row, so a readable row is rarely left behind."""
    names = ", ".join(columns)
    marks = ", ".join("?" for _ in columns)
    insert = f"INSERT OR IGNORE INTO main.{table} ({names}) VALUES ({marks})"
    read = source or table
    copied = stretches = failures = 0
    last = 0
    failed_at: int | None = None
    step = 1
    while time.monotonic() < deadline:
        rows, whole = _read_from(src, read, names, last)
        if failed_at is not None and rows:  # back past the bad stretch: probe what was skipped
            rows = _probe(src, read, names, failed_at, rows[0][0] - 1) + rows
            failed_at = None
        for row in rows:
            try:
                dest.execute(insert, row[1:])
                copied += 1
            except sqlite3.Error:
                continue
        advanced = bool(rows) and rows[-1][0] > last
        if rows:
            last = max(last, rows[-1][0])
        if whole and not advanced and rows:
            whole = False  # row ids out of order (a damaged page): step over them
        if whole:
            if len(rows) < _BLOCK:
                break  # the end of the table
            failures, step = 0, 1
            continue
        if failed_at is None:
            failed_at = last
            stretches += 1
        failures += 1
        if failures > _MAX_SKIPS:
            break
        last += step
        step *= 2
    return copied, stretches


def _text(raw: bytes) -> str | bytes:
    """Text as text; undecodable text kept as the bytes it is, not refused."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw


def _bounded(conn: sqlite3.Connection, deadline: float) -> guard.Bounds:
    """Every statement on `conn` ends by the salvage's deadline; no value over the cell bound."""
    bounds = guard.Bounds(conn)
    bounds.until = deadline
    return bounds


def _refused(bounds: guard.Bounds, db: str = "main") -> dict[str, str]:
    """The journal tables of `db` that are there but are not real tables of the journal's
    shape (a view, a virtual table...): never read. {} if the schema cannot be read."""
    try:
        found = guard.unsound(bounds, db)
    except (sqlite3.Error, schema.StoreError):
        return {}
    return {table: why for table, why in found.items() if why != "missing"}


def _open_damaged(src: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(read_uri(src), uri=True, isolation_level=None)
    conn.text_factory = _text
    return conn


def _open_copy(src: Path, work: Path) -> sqlite3.Connection:
    """A private copy of `src` (and its log, if that may be read) to read row by row: a
    truncated file is padded to the size its header gives, so that its schema and early
    pages read."""
    copy = work / "damaged.db"
    files.copy_regular(src, copy)
    if files.inspect(src).wal_refused is None:
        with contextlib.suppress(OSError, schema.StoreError):
            files.copy_regular(f"{src}-wal", f"{copy}-wal", files.WAL_MAX_BYTES)
    with copy.open("r+b") as f:
        header = f.read(100)
        if len(header) == 100:
            pages = int.from_bytes(header[28:32], "big")
            size = int.from_bytes(header[16:18], "big")
            size = 65536 if size == 1 else size
            want = pages * size
            if 0 < want <= _MAX_PAD_BYTES and f.seek(0, 2) < want:
                f.truncate(want)
    conn = sqlite3.connect(copy, isolation_level=None)
    conn.text_factory = _text
    return conn


def refuse_existing(dest: Path) -> None:
    """StoreError if anything is at `dest` or where SQLite would put its companions, a
    dangling symlink included (SQLite would follow it and write at its target)."""
    for path in (dest, *(Path(f"{dest}{suffix}") for suffix in files.COMPANIONS)):
        if os.path.lexists(path):
            raise schema.StoreError(f"{path} exists: refusing to overwrite it")


def _copy_raw(out: sqlite3.Connection, table: str, columns: list[str], deadline: float) -> int:
    """What `.recover` rebuilt of `table` into the new journal; row by row past a value
    over the cell bound (such a row is not saved)."""
    names = ", ".join(columns)
    try:
        out.execute(f"INSERT OR IGNORE INTO main.{table} ({names}) SELECT {names} FROM raw.{table}")
    except sqlite3.Error:
        _copy_by_blocks(out, out, table, columns, deadline, source=f"raw.{table}")
    return _count(out, f"main.{table}") or 0


def salvage(src: Path, dest: Path, limit_s: float = SALVAGE_S) -> Salvage:
    """Every readable row of the journal `src` into a new journal at `dest` (must not exist).

    Reads `src` without changing it (its write-ahead log is read only when it is there,
    a file and sound). Tables that are not real tables (a view put in one's place) are
    never read. Every statement ends by `limit_s` from the start.
    """
    refuse_existing(dest)
    tables = journal_tables()
    deadline = time.monotonic() + limit_s
    with scratch.directory("recover") as work:
        raw = work / "raw.db"
        why = recover_with_cli(src, raw)
        method = "sqlite3 .recover" if why is None else "row by row"
        result = Salvage(method=method)
        if why is not None:
            result.note = why
        with contextlib.closing(_new_journal(dest)) as out:
            out_bounds = _bounded(out, deadline)
            refused: dict[str, str] = {}
            found: set[str] = set()
            if why is None:
                out.execute("ATTACH ? AS raw", (f"file:{raw}?mode=ro",))
                found = {str(n) for (n,) in out.execute("SELECT name FROM raw.sqlite_master")}
                refused = _refused(out_bounds, "raw")
                if "lost_and_found" in found:
                    result.lost_and_found = _count(out, "raw.lost_and_found") or 0
            src_conn: sqlite3.Connection | None = None
            counter: sqlite3.Connection | None = None
            uncountable: dict[str, str] = {}
            try:
                with contextlib.suppress(sqlite3.Error, schema.StoreError):
                    counter = _open_damaged(src)
                    uncountable = _refused(_bounded(counter, deadline))
                if why is not None:
                    src_conn = _open_copy(src, work)
                    refused = _refused(_bounded(src_conn, deadline))
                out.execute("BEGIN")
                for table in tables:
                    if table in refused:
                        result.problems.append(
                            f"table {table} is {refused[table]}: nothing saved from it"
                        )
                        result.rows[table] = 0
                        continue
                    if src_conn is None:
                        have = _columns(out, table, "raw") if table in found else []
                    else:
                        try:
                            have = _columns(src_conn, table)
                        except sqlite3.Error:
                            have = []
                    if not have:
                        result.problems.append(f"table {table} is missing: nothing saved from it")
                        result.rows[table] = 0
                        continue
                    columns = [c for c in _columns(out, table) if c in have]
                    result.source_rows[table] = (
                        _count(counter, table) if counter and table not in uncountable else None
                    )
                    if src_conn is None:
                        result.rows[table] = _copy_raw(out, table, columns, deadline)
                    else:
                        copied, bad = _copy_by_blocks(src_conn, out, table, columns, deadline)
                        result.rows[table] = copied
                        if bad:
                            result.problems.append(
                                f"{table}: {bad} unreadable stretch{'es' if bad > 1 else ''}"
                            )
                    if time.monotonic() >= deadline:
                        result.problems.append(f"{table}: salvage stopped after {limit_s} s")
                out.execute("COMMIT")
            finally:
                if counter is not None:
                    counter.close()
                if src_conn is not None:
                    src_conn.close()
    return result
