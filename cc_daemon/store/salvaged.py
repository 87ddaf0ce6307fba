"""What the read side learnt of a journal, kept until the file changes: its checks and its
salvaged copy.

Judging a journal costs: SQLite's `quick_check` reads the whole file (0.39 s for
91 MB), the log's frames are checksummed one by one, and a damaged journal is
copied and salvaged (seconds, and a copy the size of the file). The field page
opens a reader for every request, so without this it did all of that again each
time: 6.5 to 9 s a request, and a new copy in the temporary directory each time.

This module owns doing each of them once per state of the file, for the life of
the process, in bounded room:
- `quick_check` once per change of the journal file (its device, inode, size
  and modification time; the daemon changes the file only at a checkpoint);
- the log's frames through one `WalCheck` (a log that only grew is checked from
  where it was left);
- a salvaged copy once per change of the file or its log, at most `MAX_COPIES`
  kept (the oldest is removed when another is made: a reader still reading it
  keeps its open file), all in one private directory (`store.scratch`) that is
  removed when the process ends (`atexit`) or swept by the next process if this
  one is killed.

Thread-safe: the field page reads on several threads; two requests for the same
state wait for one salvage. It never writes a journal nor anything beside it.
"""

from __future__ import annotations

import atexit
import itertools
import sqlite3
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import TypeVar

from cc_daemon.store import damage, scratch
from cc_daemon.store.damage import Salvage
from cc_daemon.store.walcheck import WalCheck

MAX_COPIES = 2
MAX_CHECKS = 32

T = TypeVar("T")


class Salvaged:
    """The checks and salvaged copies of one process (`shared()` gives its one)."""

    def __init__(self, max_copies: int = MAX_COPIES) -> None:
        self.max_copies = max_copies
        self.wal_damage = WalCheck()
        self._lock = threading.Lock()
        self._gates: dict[Hashable, threading.Lock] = {}
        self._checks: OrderedDict[Hashable, list[str]] = OrderedDict()
        self._copies: OrderedDict[Hashable, tuple[Path, Salvage]] = OrderedDict()
        self._names = itertools.count(1)
        self._directory: Path | None = None
        # What was done, for the page's figures and the tests: a fact, not a guess.
        self.checks_run = 0
        self.salvages_run = 0

    def _once(
        self,
        table: OrderedDict[Hashable, T],
        key: Hashable,
        make: Callable[[], T],
        keep: int,
        forget: Callable[[T], None] = lambda _: None,
    ) -> T:
        """`table[key]`, made by `make` if it is not there (by one thread: the others
        wait for it); past `keep` entries the oldest is dropped and `forget` called."""
        with self._lock:
            if key in table:
                table.move_to_end(key)
                return table[key]
            gate = self._gates.setdefault((id(table), key), threading.Lock())
        with gate:
            with self._lock:
                if key in table:
                    return table[key]
            try:
                value = make()  # outside the lock: other states are served meanwhile
            except BaseException:
                with self._lock:
                    self._gates.pop((id(table), key), None)
                raise
            with self._lock:
                table[key] = value
                self._gates.pop((id(table), key), None)
                while len(table) > keep:
                    forget(table.popitem(last=False)[1])
            return value

    def quick_check(self, key: Hashable, run: Callable[[], list[str]]) -> list[str]:
        """`run` (SQLite's check of the file) once per `key`: what it found."""

        def check() -> list[str]:
            found = run()
            self.checks_run += 1
            return found

        found: list[str] = self._once(self._checks, key, check, MAX_CHECKS)
        return list(found)

    def open_copy(self, src: Path, key: Hashable) -> tuple[sqlite3.Connection, Salvage]:
        """A read-only connection to the salvaged copy of `src` in the state `key`, made
        once; StoreError if nothing could be saved."""

        def make() -> tuple[Path, Salvage]:
            directory = self._private()
            dest = directory / f"{next(self._names)}-{src.name}"
            try:
                saved = damage.salvage(src, dest)
            except BaseException:
                dest.unlink(missing_ok=True)
                raise
            self.salvages_run += 1
            return dest, saved

        copy, saved = self._once(
            self._copies, key, make, self.max_copies, lambda old: old[0].unlink(missing_ok=True)
        )
        with self._lock:  # opened before another salvage can push it out
            conn = sqlite3.connect(f"{copy.as_uri()}?immutable=1", uri=True, isolation_level=None)
        return conn, saved

    def _private(self) -> Path:
        with self._lock:
            if self._directory is None:
                self._directory = scratch.make("salvage")
            return self._directory

    @property
    def directory(self) -> Path | None:
        """Where its copies are (None until the first salvage, and after `close`)."""
        return self._directory

    def room(self) -> int:
        """The bytes its copies take now."""
        with self._lock:
            return sum(p.stat().st_size for p, _ in self._copies.values() if p.exists())

    def close(self) -> None:
        """Remove every copy (readers still reading one keep their open file)."""
        with self._lock:
            self._copies.clear()
            self._checks.clear()
            directory, self._directory = self._directory, None
        if directory is not None:
            scratch.remove(directory)


_SHARED: list[Salvaged] = []  # the process's one, once made
_SHARED_LOCK = threading.Lock()


def shared() -> Salvaged:
    """The process's one `Salvaged`; made by the first reader, which first sweeps away
    what killed processes left in the temporary directory."""
    with _SHARED_LOCK:
        if not _SHARED:
            scratch.sweep()
            _SHARED.append(Salvaged())
            atexit.register(_SHARED[0].close)
        return _SHARED[0]
