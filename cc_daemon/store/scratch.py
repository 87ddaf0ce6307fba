"""The read side's private temporary directories, named so that a killed process's are found.

A reader copies a journal it may not read in place, and salvages a damaged one,
into a directory of its own under the temporary directory. Each is named
`cc-daemon-<kind>-<pid>-<start>-<random>`: the process's id and its start time
(the kernel's, in clock ticks since boot, so a reused pid is not taken for the
process that made the directory). A process removes its own on every way out
it can see (a `with` block, `atexit`); one killed with SIGKILL cannot, and
`sweep` (run by the first reader of every process) removes what such a
process left: directories of this user whose process is gone.

It never removes a directory that is not a real directory, not this user's, or
whose process still runs.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

KINDS = ("read", "salvage", "recover")
_NAME = re.compile(r"cc-daemon-(read|salvage|recover)-(\d+)-(\d+)-")


def _start_ticks(pid: int) -> int:
    """The process's start time in clock ticks since boot (0 where /proc cannot say)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0
    # The command name (field 2) may hold spaces and parentheses: count from the last ')'.
    fields = text[text.rfind(")") + 2 :].split()
    try:
        return int(fields[19])  # field 22 of proc(5)
    except (IndexError, ValueError):
        return 0


def make(kind: str) -> Path:
    """A new private directory (mode 0700) for `kind` ("read", "salvage", "recover")."""
    pid = os.getpid()
    return Path(tempfile.mkdtemp(prefix=f"cc-daemon-{kind}-{pid}-{_start_ticks(pid)}-"))


def remove(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


@contextlib.contextmanager
def directory(kind: str) -> Iterator[Path]:
    """A private directory for the block, removed at its end however it ends."""
    path = make(kind)
    try:
        yield path
    finally:
        remove(path)


def _alive(pid: int, start: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process: not ours to judge
    return start == 0 or _start_ticks(pid) in (0, start)


def sweep(where: Path | None = None) -> int:
    """Remove what killed processes of this user left; returns how many directories."""
    root = Path(where or tempfile.gettempdir())
    removed = 0
    try:
        names = os.listdir(root)
    except OSError:
        return 0
    uid = os.geteuid()
    for name in names:
        found = _NAME.match(name)
        if found is None:
            continue
        path = root / name
        try:
            st = os.lstat(path)
        except OSError:
            continue
        if not stat.S_ISDIR(st.st_mode) or st.st_uid != uid:
            continue
        if _alive(int(found.group(2)), int(found.group(3))):
            continue
        remove(path)
        removed += 1
    return removed
