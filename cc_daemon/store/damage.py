"""Damaged journals: finding the damage, and saving every row that can be read.

This module owns judging a journal file (SQLite's `quick_check`, and a check of
the write-ahead log's frames, whose damage SQLite itself passes over in
silence: it stops reading the log at the first bad frame) and salvaging one
into a new journal: SQLite's own `.recover` through the `sqlite3` program where
there is one, else row by row, in blocks of row ids, skipping what cannot be
read. It never writes the damaged file nor anything beside it.
"""

from __future__ import annotations

import contextlib
import shutil
import sqlite3
import struct
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cc_daemon.store import schema

WAL_MAGIC_LE = 0x377F0682
WAL_MAGIC_BE = 0x377F0683
_WAL_HEADER = 32
_FRAME_HEADER = 24
# `quick_check` messages kept: enough to name the damage, few enough for a line.
CHECK_LIMIT = 5
_BLOCK = 256  # row ids read at once while salvaging row by row
_MAX_PROBES = 4096  # row ids tried one by one after a bad stretch
_MAX_SKIPS = 48  # doubling steps past a bad stretch before giving up on a table
SALVAGE_S = 120.0
_MAX_PAD_BYTES = (
    4 << 30
)  # a header claiming more is itself damaged  # a salvage's time for all tables together
RECOVER_TIMEOUT_S = 600.0


def _checksum(data: bytes, s0: int, s1: int, big_endian: bool) -> tuple[int, int]:
    words = struct.unpack(f"{'>' if big_endian else '<'}{len(data) // 4}I", data)
    for i in range(0, len(words), 2):
        s0 = (s0 + words[i] + s1) & 0xFFFFFFFF
        s1 = (s1 + words[i + 1] + s0) & 0xFFFFFFFF
    return s0, s1


def wal_damage(db: Path) -> str | None:
    """What is wrong with `db`'s write-ahead log, if frames SQLite will not read follow
    a bad one (a torn last write, with nothing after it, is not damage)."""
    try:
        data = Path(f"{db}-wal").read_bytes()
    except OSError:
        return None
    if len(data) < _WAL_HEADER:
        return None
    magic, _, page_size, _, salt1, salt2, c0, c1 = struct.unpack(">8I", data[:_WAL_HEADER])
    size = _FRAME_HEADER + page_size
    frames = (len(data) - _WAL_HEADER) // size if page_size else 0
    if magic not in (WAL_MAGIC_LE, WAL_MAGIC_BE) or page_size < 512:
        return f"the write-ahead log's header is damaged: its {frames} frames are not read"
    big = magic == WAL_MAGIC_BE
    s0, s1 = _checksum(data[:24], 0, 0, big)
    if (s0, s1) != (c0, c1):
        return f"the write-ahead log's header is damaged: its {frames} frames are not read"
    bad: int | None = None
    for n in range(frames):
        at = _WAL_HEADER + n * size
        header = data[at : at + _FRAME_HEADER]
        f_salt1, f_salt2, f0, f1 = struct.unpack(">4I", header[8:24])
        current = (f_salt1, f_salt2) == (salt1, salt2)
        if bad is None:
            s0, s1 = _checksum(header[:8], s0, s1, big)
            s0, s1 = _checksum(data[at + _FRAME_HEADER : at + size], s0, s1, big)
            if not current or (s0, s1) != (f0, f1):
                bad = n
        elif current:
            return (
                f"the write-ahead log is damaged at frame {bad + 1} of {frames}:"
                f" the last {frames - bad} frames (the newest rows) are not read"
            )
    return None


def quick_check(conn: sqlite3.Connection) -> list[str]:
    """SQLite's `quick_check` of the open file: [] when it is sound."""
    rows = conn.execute(f"PRAGMA quick_check({CHECK_LIMIT})").fetchall()
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
    with contextlib.closing(sqlite3.connect(":memory:", isolation_level=None)) as conn:
        schema.migrate(conn)
        names = conn.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY rowid"
        ).fetchall()
    return [str(name) for (name,) in names]


def _new_journal(dest: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(dest, isolation_level=None)
    conn.execute(f"PRAGMA application_id = {schema.APPLICATION_ID}")
    schema.migrate(conn)
    return conn


def _columns(conn: sqlite3.Connection, table: str, db: str = "main") -> list[str]:
    return [str(row[1]) for row in conn.execute(f"PRAGMA {db}.table_info({table})")]


def _recover_with_cli(src: Path, raw: Path) -> str | None:
    """SQLite's `.recover` of `src` into the new file `raw`; None, or why it failed.

    Some builds of the sqlite3 program cannot recover (no `sqlite_dbpage`:
    "SQL logic error"); then the caller salvages row by row."""
    cli = shutil.which("sqlite3")
    if cli is None:
        return "no sqlite3 program"
    uri = f"file:{src.resolve()}?{_read_mode(src)}"
    errors = raw.with_suffix(".err")
    try:
        with (
            errors.open("wb") as err,
            subprocess.Popen(
                [cli, "-readonly", uri, ".recover"],
                stdout=subprocess.PIPE,
                stderr=err,
                stdin=subprocess.DEVNULL,
            ) as dump,
        ):
            load = subprocess.run(
                [cli, str(raw)],
                stdin=dump.stdout,
                capture_output=True,
                timeout=RECOVER_TIMEOUT_S,
                check=False,
            )
            if dump.stdout is not None:
                dump.stdout.close()
            dumped = dump.wait(timeout=RECOVER_TIMEOUT_S)
        said = errors.read_text(errors="replace").strip()
    except (OSError, subprocess.SubprocessError) as exc:
        return f"sqlite3 .recover failed: {exc}"
    if dumped != 0 or load.returncode != 0 or said:
        why = said or load.stderr.decode(errors="replace").strip() or f"exit {dumped}"
        with contextlib.suppress(OSError):
            raw.unlink()
        return f"sqlite3 .recover failed ({why.splitlines()[0][:120]})"
    return None


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
) -> tuple[int, int]:
    """Copy what can be read of `table` in row id order, stepping over what cannot.

    Returns (rows copied, unreadable stretches met). Past a bad page the next
    readable row id is searched for by doubling steps, then the stretch skipped
    is probed row by row, so a readable row is rarely left behind."""
    names = ", ".join(columns)
    marks = ", ".join("?" for _ in columns)
    insert = f"INSERT OR IGNORE INTO main.{table} ({names}) VALUES ({marks})"
    copied = stretches = failures = 0
    last = 0
    failed_at: int | None = None
    step = 1
    while time.monotonic() < deadline:
        rows, whole = _read_from(src, table, names, last)
        if failed_at is not None and rows:  # back past the bad stretch: probe what was skipped
            rows = _probe(src, table, names, failed_at, rows[0][0] - 1) + rows
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


def _read_mode(src: Path) -> str:
    """As the reader opens: immutable when nobody has it open, so nothing is made beside it."""
    return "mode=ro" if Path(f"{src}-wal").exists() else "immutable=1"


def _open_damaged(src: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(
        f"file:{src.resolve()}?{_read_mode(src)}", uri=True, isolation_level=None
    )
    conn.text_factory = _text
    return conn


def _open_copy(src: Path, work: Path) -> sqlite3.Connection:
    """A private copy of `src` (and its log) to read row by row: a truncated file is
    padded to the size its header gives, so that its schema and early pages read."""
    copy = work / "damaged.db"
    shutil.copyfile(src, copy)
    with contextlib.suppress(OSError):
        shutil.copyfile(f"{src}-wal", f"{copy}-wal")
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


def salvage(src: Path, dest: Path, limit_s: float = SALVAGE_S) -> Salvage:
    """Every readable row of the journal `src` into a new journal at `dest` (must not exist).

    Reads `src` without changing it (its write-ahead log is read by `.recover`
    only when it is there and sound). Raises StoreError if nothing could be read.
    """
    if dest.exists():
        raise schema.StoreError(f"{dest} exists: refusing to overwrite it")
    tables = journal_tables()
    deadline = time.monotonic() + limit_s
    with tempfile.TemporaryDirectory(prefix="cc-daemon-recover-") as work:
        raw = Path(work) / "raw.db"
        why = _recover_with_cli(src, raw)
        method = "sqlite3 .recover" if why is None else "row by row"
        result = Salvage(method=method)
        if why is not None:
            result.note = why
        with contextlib.closing(_new_journal(dest)) as out:
            if why is None:
                out.execute("ATTACH ? AS raw", (f"file:{raw}?mode=ro",))
                found = {str(n) for (n,) in out.execute("SELECT name FROM raw.sqlite_master")}
                if "lost_and_found" in found:
                    result.lost_and_found = _count(out, "raw.lost_and_found") or 0
            src_conn: sqlite3.Connection | None = None
            counter: sqlite3.Connection | None = None
            try:
                with contextlib.suppress(sqlite3.Error):
                    counter = _open_damaged(src)
                if why is not None:
                    src_conn = _open_copy(src, Path(work))
                out.execute("BEGIN")
                for table in tables:
                    if table == "sqlite_sequence":
                        continue
                    if src_conn is None:
                        have = _columns(out, table, "raw") if table in found else []
                        reader, prefix = out, "raw."
                    else:
                        try:
                            have = _columns(src_conn, table)
                        except sqlite3.Error:
                            have = []
                        reader, prefix = src_conn, ""
                    if not have:
                        result.problems.append(f"table {table} is missing: nothing saved from it")
                        result.rows[table] = 0
                        continue
                    columns = [c for c in _columns(out, table) if c in have]
                    result.source_rows[table] = _count(counter, table) if counter else None
                    if src_conn is None:
                        names = ", ".join(columns)
                        out.execute(
                            f"INSERT OR IGNORE INTO main.{table} ({names})"
                            f" SELECT {names} FROM {prefix}{table}"
                        )
                        result.rows[table] = _count(out, f"main.{table}") or 0
                    else:
                        copied, bad = _copy_by_blocks(reader, out, table, columns, deadline)
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
