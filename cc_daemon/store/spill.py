"""Rows the journal cannot write yet, kept on a filesystem that still works.

This module owns the spill files: where they may go, writing rows to them
durably as JSON lines, reading them back for replay and removing them once
replayed. A journal whose filesystem fails (read-only after an I/O error, full,
frozen) spills there while it waits, so a power cut or a bounded buffer cannot
take rows that no file holds. It never touches SQLite nor the rows' meaning:
each line carries the row as recorded (`row`, for replay by this run) beside
the readable record the journal makes of it.

Where: beside the journal, then the configured `store.spill_dir` (a second
card), the service's state directory, then the runtime directories (systemd's
`$RUNTIME_DIRECTORY`, `$XDG_RUNTIME_DIR/cc-daemon`, `/run/cc-daemon`, the
last two made if missing): tmpfs,
lost at power off, but working when the card has failed. Never the temporary
directory (PrivateTmp wipes it), never under /dev, /proc or /sys.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cc_daemon.store.failures import data_directories, state_directories, unused_path

DEFAULT_FILE_MODE = 0o640
# The system's runtime directory for us when systemd made none (tests move it).
SYSTEM_RUNTIME_DIR = Path("/run/cc-daemon")


def runtime_directories(*, make: bool = True) -> list[Path]:
    """The runtime directories, systemd's first: memory-backed, working when a card fails.
    `make`: ours are made if missing (to spill into; not to look for files)."""
    ours = [SYSTEM_RUNTIME_DIR]  # ours to make if missing
    xdg = os.environ.get("XDG_RUNTIME_DIR", "")
    if xdg:
        ours.insert(0, Path(xdg) / "cc-daemon")
    for directory in ours if make else ():
        with contextlib.suppress(OSError):
            directory.mkdir(mode=0o750, exist_ok=True)
    runtime = os.environ.get("RUNTIME_DIRECTORY", "").split(":")[0]
    return [Path(runtime), *ours] if runtime else ours


def spill_directories(journal: Path, configured: Path | None, *, make: bool = True) -> list[Path]:
    """Where a spill file may go, in order of preference (see the module's docstring);
    `make`: the runtime directories are made if missing (not when only looking)."""
    candidates = [journal.parent]
    if configured is not None:
        candidates.append(configured)
    candidates += state_directories()
    candidates += runtime_directories(make=make)
    return data_directories(candidates)


def _create(path: Path, mode: int) -> int:
    """A new file at `path` with exactly `mode` (whatever the umask); its descriptor."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND | os.O_CLOEXEC, mode)
    try:
        os.fchmod(fd, mode)
    except OSError:
        os.close(fd)
        raise
    return fd


def create_file(path: Path, mode: int) -> None:
    """Create an empty `path` with `mode` if it does not exist (SQLite keeps its mode)."""
    with contextlib.suppress(FileExistsError):
        os.close(_create(path, mode))


def _append(fd: int, data: bytes) -> None:
    """Write all of `data` at the end of `fd` and fsync; on failure cut what was written."""
    start = os.lseek(fd, 0, os.SEEK_END)
    try:
        view = memoryview(data)
        while view:
            written = os.write(fd, view)
            view = view[written:]
        os.fsync(fd)
    except OSError:
        with contextlib.suppress(OSError):
            os.ftruncate(fd, start)  # a reader skips a torn line anyway
        raise


class SpillFiles:
    """The spill files of one run: append rows while the journal fails, take them back.

    Used by the journal's writer thread only.
    """

    def __init__(
        self,
        name: Callable[[], str],
        directories: Callable[[], list[Path]],
        mode: int = DEFAULT_FILE_MODE,
    ) -> None:
        self._name = name  # a fresh file name (it carries a UTC stamp)
        self._directories = directories
        self._mode = mode
        self._fd: int | None = None
        self.files: list[Path] = []  # oldest first; rows in them wait for replay
        self.rows = 0

    def append(self, lines: list[str]) -> Path | None:
        """Write `lines` durably to the current file, else a new one; the file, or None."""
        data = "".join(line + "\n" for line in lines).encode()
        if self._fd is not None:
            try:
                _append(self._fd, data)
                self.rows += len(lines)
                return self.files[-1]
            except OSError:
                self._close_fd()  # that filesystem failed too: the next one
        for directory in self._directories():
            try:
                target = unused_path(directory / self._name())
                fd = _create(target, self._mode)
            except OSError:
                continue
            try:
                _append(fd, data)
            except OSError:
                os.close(fd)
                with contextlib.suppress(OSError):
                    target.unlink()
                continue
            self._fd = fd
            self.files.append(target)
            self.rows += len(lines)
            return target
        return None

    def take(self) -> tuple[list[list[Any]], int]:
        """Every row spilled so far, oldest first, and how many lines could not be read.

        The files stay until `forget` (after the rows are safely elsewhere)."""
        self._close_fd()
        rows: list[list[Any]] = []
        unreadable = 0
        for path in self.files:
            try:
                text = path.read_bytes().decode("utf-8", errors="replace")
            except OSError:
                unreadable += 1
                continue
            for line in text.splitlines():
                try:
                    row = json.loads(line)["row"]
                except (ValueError, KeyError, TypeError):
                    unreadable += 1
                    continue
                if isinstance(row, list) and row:
                    rows.append(row)
                else:
                    unreadable += 1
        return rows, unreadable

    def forget(self, paths: list[Path]) -> list[Path]:
        """Remove `paths` (their rows are elsewhere now); return those that stay."""
        if self.files and self.files[-1] in paths:
            self._close_fd()
        kept = []
        for path in paths:
            try:
                path.unlink()
            except FileNotFoundError:
                pass
            except OSError:
                kept.append(path)
        self.files = [path for path in self.files if path not in paths]
        return kept

    def close(self) -> None:
        self._close_fd()

    def _close_fd(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)
