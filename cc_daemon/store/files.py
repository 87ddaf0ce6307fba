"""A journal's files on disk, judged before anything opens them.

A journal copied from someone else (scp, a USB stick) may hold, where a file
belongs, a FIFO (opening it for reading waits for a writer that never comes), a
device (`/dev/zero` and `/dev/urandom` never end), a directory, a socket, a
symlink to any of these, or a write-ahead log far bigger than any the daemon
lets grow. This module owns that judgement for the journal, its `-wal`, `-shm`
and `-journal`, what identifies one state of them (the key the read side caches
its checks and salvaged copies by), and the only ways the read side opens or
copies such a file itself: `stat` first, then `open` with O_NONBLOCK (a FIFO
swapped in meanwhile cannot block), `fstat` again, and a bounded read.

It never writes a journal's files, and never opens a file it has not judged.
"""

from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path
from typing import BinaryIO, NamedTuple

from cc_daemon.store.schema import StoreError

# The daemon checkpoints its log at 4 MB (SQLite's 1000 pages); a log sixteen times
# that is none it wrote, and checking its frames would take the reader minutes.
WAL_MAX_BYTES = 64 << 20
COMPANIONS = ("-wal", "-shm", "-journal")

_KINDS = (
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISSOCK, "a socket"),
)


class NotAFileError(StoreError):
    """A path where a journal's file belongs holds something else; never opened."""


def _what(mode: int) -> str:
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a regular file"


def odd(path: Path | str) -> str | None:
    """None when nothing is at `path`, or a regular file (or a symlink to one);
    else what is there instead ("a FIFO", "a character device", "a dangling symlink")."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "a dangling symlink" if os.path.islink(path) else None
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"
    return None if stat.S_ISREG(st.st_mode) else _what(st.st_mode)


def size_text(size: int) -> str:
    if size >= 1 << 30:
        return f"{size / (1 << 30):.1f} GiB"
    if size >= 1 << 20:
        return f"{size / (1 << 20):.0f} MiB"
    return f"{size / 1024:.0f} KiB"


def open_regular(path: Path | str, max_bytes: int | None = None) -> BinaryIO:
    """`path` opened for reading, if it is a regular file (of at most `max_bytes`);
    NotAFileError otherwise, without opening what is not one."""
    found = odd(path)
    if found is not None:
        raise NotAFileError(f"{path} is {found}, not a file")
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):  # swapped since the stat above
            raise NotAFileError(f"{path} is {_what(st.st_mode)}, not a file")
        if max_bytes is not None and st.st_size > max_bytes:
            raise NotAFileError(
                f"{path} is {size_text(st.st_size)}, over the {size_text(max_bytes)} read"
            )
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def copy_regular(src: Path | str, dest: Path | str, max_bytes: int | None = None) -> None:
    """Copy the regular file `src` (refused as `open_regular` refuses) to the new `dest`."""
    with open_regular(src, max_bytes) as source, open(dest, "xb") as out:
        shutil.copyfileobj(source, out, 1 << 20)


class Stamp(NamedTuple):
    """What changes when a file changes: device, inode, size, modification time."""

    dev: int
    ino: int
    size: int
    mtime_ns: int


def stamp(path: Path | str) -> Stamp | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return Stamp(st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


class JournalFiles(NamedTuple):
    """The verdict on a journal and its companions, before SQLite opens any of them."""

    path: Path
    wal: bool  # a -wal is beside it (sound or not)
    wal_refused: str | None  # why its -wal must not be read: not a file, or too big
    odd_companions: tuple[str, ...]  # -shm or -journal that is not a file: never let SQLite open it

    @property
    def key(self) -> tuple[Stamp | None, Stamp | None]:
        """One state of the journal: its file and its log (the salvage cache's key)."""
        return stamp(self.path), stamp(f"{self.path}-wal")


def wal_refused(wal: Path) -> str | None:
    """Why the write-ahead log `wal` must not be read (not a file, or too big); None if
    it may (or is not there)."""
    found = odd(wal)
    if found is not None:
        return f"the write-ahead log {wal.name} is {found}, not a file: it is not read"
    size = stamp(wal)
    if size is not None and size.size > WAL_MAX_BYTES:
        return (
            f"the write-ahead log {wal.name} is {size_text(size.size)}, over the"
            f" {size_text(WAL_MAX_BYTES)} any the daemon writes: it is not read"
        )
    return None


def inspect(path: Path) -> JournalFiles:
    """Judge `path` and its companions; StoreError if `path` is no journal file at all."""
    found = odd(path)
    if found is not None:
        raise NotAFileError(f"{path} is {found}, not a journal file")
    if not path.exists():
        raise StoreError(f"no journal at {path}")
    wal = Path(f"{path}-wal")
    others = tuple(
        f"{path.name}{suffix} is {kind}"
        for suffix in COMPANIONS[1:]
        if (kind := odd(f"{path}{suffix}")) is not None
    )
    return JournalFiles(path, os.path.lexists(wal), wal_refused(wal), others)
