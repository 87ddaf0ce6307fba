"""`cc-daemon recover`: every readable row of a damaged journal into a new one.

This module owns the command's surface: its arguments, the report of what was
saved and what was lost, and its exit status (0 every row the damaged file
still counts was saved and no damage was found; 1 something was or may have
been lost, or nothing could be read; 2 wrong arguments, or NEW or one of its
companions exists, a dangling symlink included). The salvage itself is
`store.damage.salvage` (SQLite's own `.recover` where the sqlite3 program can,
else row by row; tables that are views are never run, every statement ends by
the salvage's time bound). It never writes the damaged file nor anything
beside it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cc_daemon.store import damage, files
from cc_daemon.store.schema import StoreError


def add_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "recover",
        help="save every readable row of a damaged journal into a new journal",
        description="Read a damaged journal (corrupt pages, a truncated file, a torn"
        " write-ahead log, missing tables) without changing it, write every row that"
        " can be read into a new journal, and report what was lost. Exit status 0:"
        " nothing lost that the file still counts; 1: rows lost (or possibly lost);"
        " 2: wrong arguments.",
    )
    p.add_argument("--db", type=Path, required=True, metavar="DAMAGED", help="the damaged journal")
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        metavar="NEW",
        help="the new journal (refused if it exists)",
    )
    p.set_defaults(handler=run)


def _say(text: str) -> None:
    print(text, flush=True)


def run(args: argparse.Namespace) -> int:
    src: Path = args.db
    dest: Path = args.output
    try:
        files.inspect(src)
    except StoreError as exc:
        print(f"cc-daemon recover: {exc}", file=sys.stderr)
        return 1
    try:
        # A dangling symlink too: SQLite would follow it and write at its target.
        damage.refuse_existing(dest)
    except StoreError as exc:
        print(f"cc-daemon recover: {exc}", file=sys.stderr)
        return 2
    wal = damage.wal_damage(src)
    try:
        result = damage.salvage(src, dest)
    except (StoreError, OSError) as exc:
        print(f"cc-daemon recover: cannot recover {src}: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # a salvage must report, never trace back
        print(f"cc-daemon recover: cannot recover {src}: {exc!r}", file=sys.stderr)
        dest.unlink(missing_ok=True)
        return 1
    lost: list[str] = list(result.problems)
    if wal is not None:
        lost.append(wal)
    how = f"{result.method}: {result.note}" if result.note else result.method
    _say(f"recovered {src} into {dest} ({how}):")
    for table, saved in result.rows.items():
        counted = result.source_rows.get(table)
        if counted is None:
            note = "the damaged file cannot count its own: some may be lost"
            lost.append(f"{table}: cannot tell how many rows were lost")
        elif saved < counted:
            note = f"of {counted}: {counted - saved} LOST"
            lost.append(f"{table}: {counted - saved} rows lost")
        else:
            note = f"of {counted}"
        _say(f"  {table:<15} {saved:>9} rows  {note}")
    if result.lost_and_found:
        _say(f"  lost_and_found  {result.lost_and_found:>9} rows SQLite found but could not place")
    if lost:
        print(
            f"cc-daemon recover: lost or damaged: {'; '.join(dict.fromkeys(lost))}", file=sys.stderr
        )
        return 1
    _say("nothing lost")
    return 0
