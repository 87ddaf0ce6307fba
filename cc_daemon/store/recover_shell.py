"""SQLite's own `.recover` through the `sqlite3` program, with the loading shell in safe mode.

`.recover` (where the program is built with `sqlite_dbpage`) reads a damaged
file page by page and prints SQL that rebuilds what it found; a second `sqlite3`
runs that SQL into a new file. That SQL carries the damaged file's own schema
text and values, and the shell runs dot-commands and functions besides SQL
(`.shell`, `.system`, `writefile()`, `edit()`): a hostile file's schema can end
one statement and start another. So the loading shell runs with `-safe`, which
refuses every command and function that touches a file or runs a program; a
`sqlite3` without `-safe` (before 3.37) is not used at all.

This module owns that pipeline. It never writes the damaged file, and never
lets SQLite open a companion of it that `store.files` refused.
"""

from __future__ import annotations

import contextlib
import functools
import shutil
import subprocess
from pathlib import Path

from cc_daemon.store import files

RECOVER_TIMEOUT_S = 600.0
_PROBE_TIMEOUT_S = 10.0


@functools.cache
def has_safe_mode(cli: str) -> bool:
    """Whether this `sqlite3` program knows `-safe` (SQLite 3.37 and later)."""
    try:
        done = subprocess.run(
            [cli, "-safe", ":memory:", "SELECT 'safe'"],
            capture_output=True,
            stdin=subprocess.DEVNULL,
            timeout=_PROBE_TIMEOUT_S,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return False
    return done.returncode == 0 and done.stdout.strip() == b"safe"


def read_uri(src: Path) -> str:
    """The URI to read `src` as the reader does: `mode=ro` with a sound log beside it (and
    no odd companion for SQLite to trip on), else `immutable` (the file alone)."""
    found = files.inspect(src)
    sound_log = found.wal and found.wal_refused is None and not found.odd_companions
    return f"file:{src.resolve()}?{'mode=ro' if sound_log else 'immutable=1'}"


def recover_with_cli(src: Path, raw: Path) -> str | None:
    """SQLite's `.recover` of `src` into the new file `raw`; None, or why it failed.

    Some builds of the sqlite3 program cannot recover (no `sqlite_dbpage`:
    "SQL logic error"); then the caller salvages row by row."""
    cli = shutil.which("sqlite3")
    if cli is None:
        return "no sqlite3 program"
    if not has_safe_mode(cli):
        return "the sqlite3 program has no -safe mode"
    errors = raw.with_suffix(".err")
    try:
        with (
            errors.open("wb") as err,
            subprocess.Popen(
                [cli, "-readonly", read_uri(src), ".recover"],
                stdout=subprocess.PIPE,
                stderr=err,
                stdin=subprocess.DEVNULL,
            ) as dump,
        ):
            load = subprocess.run(
                [cli, "-safe", "-bail", str(raw)],
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
