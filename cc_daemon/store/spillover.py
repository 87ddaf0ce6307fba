"""The journal's rows while its file cannot take them: spill files and their replay.

Between the rows in memory (`buffer.RowBuffer`) and the writer thread that puts
them into SQLite (`writer.BufferedWriter`), this class owns what happens while
the file fails: after `SPILL_AFTER_S` of failure the rows in memory move to a
spill file on a filesystem that still works (`spill.SpillFiles`), and once the
file takes rows again they are replayed into it, oldest first, before anything
newer; what could be neither written nor spilled is counted as dropped. It also
keeps the account of an episode of failure and of a write that stalls. Used by
the writer thread only, except `_spill` at close.
"""

from __future__ import annotations

import contextlib
import time
from abc import ABC, abstractmethod
from pathlib import Path

from cc_daemon.store.buffer import Row, RowBuffer
from cc_daemon.store.failures import emit, utc_stamp
from cc_daemon.store.spill import DEFAULT_FILE_MODE, SpillFiles, spill_directories

# A journal failing this long spills its rows to a file that still works:
# brief trouble (a reader's lock) stays in memory.
SPILL_AFTER_S = 3.0
# A write (or open) not done after this long (a frozen or dying filesystem)
# makes `health()` say the journal is not writable, while it still waits.
STALL_S = 5.0
# Rows per transaction: enough to write a backlog fast, few enough that a
# transaction needs little free space (tens of kB) and holds the lock briefly.
MAX_TRANSACTION_ROWS = 500


class SpillOver(RowBuffer, ABC):
    """Spill files for a writer; the writer supplies `_commit` and `_spill_line`."""

    def __init__(
        self,
        path: Path,
        max_buffered_rows: int,
        spill_dir: Path | None = None,
        file_mode: int = DEFAULT_FILE_MODE,
    ) -> None:
        super().__init__(max_buffered_rows)
        self.path = Path(path)  # the configured file; health().path is the one in use
        self._active = self.path  # the file written to
        self._file_mode = file_mode
        self._spill_dir = spill_dir
        self._spilled = self._spill_files()
        # The current episode of failure: since when (monotonic, wall), the
        # first error, rows dropped before it; None while writing works.
        self._episode: tuple[float, float, str, int] | None = None
        self._busy_since: float | None = None  # a write or open in progress since
        self._rows_written = 0
        self._last_error: str | None = None

    @abstractmethod
    def _commit(self, chunk: list[Row]) -> tuple[int, int, BaseException | None]:
        """Commit `chunk` from its front: (rows done with, rows committed, the storage
        error that stopped it). The writer's (`writer.BufferedWriter`): it holds the
        connection."""

    def _spill_line(self, row: Row) -> str:
        return repr(row)

    def _spill_name(self, stamp: str) -> str:
        """A spill file of this journal: `stamp` is when it began, or `*` to find them."""
        return f"{self.path.stem}-unwritten-{stamp}.jsonl"

    def _spill_files(self) -> SpillFiles:
        return SpillFiles(
            lambda: self._spill_name(utc_stamp(time.time())),
            lambda: spill_directories(self._active, self._spill_dir),
            self._file_mode,
        )

    def leftover_spill_files(self) -> list[Path]:
        """Spill files of this journal that no run replayed (an earlier run ended, or
        died, before the journal came back): in every place a spill may go, oldest first."""
        mine = set(self._spilled.files)
        found: set[Path] = set()
        for directory in spill_directories(self._active, self._spill_dir, make=False):
            with contextlib.suppress(OSError):
                found.update(directory.glob(self._spill_name("*")))
        return sorted(found - mine, key=lambda p: (p.name, str(p)))

    def _episode_ended(self, **detail: object) -> None:
        """The journal is writable again after failing (`detail` says how it went)."""

    def _stalled_s(self) -> float | None:
        """How long the write or open in progress has taken, if over `STALL_S`."""
        since = self._busy_since
        if since is None:
            return None
        took = time.monotonic() - since
        return took if took >= STALL_S else None

    # ------------------------------------------------------------- spill

    def _spill(self, rows: list[Row]) -> Path | None:
        """Save rows to a new spill file (at close); return the file, or None."""
        try:
            lines = [self._spill_line(row) for row in rows]
            own = self._spill_files()
            target = own.append(lines)
            own.close()
            return target
        except Exception as exc:
            emit("error", "journal could not write its spill file", error=repr(exc))
            return None

    def _spill_at_close(self, rows: list[Row], *, opened: bool) -> None:
        """At close, after the writer ended: save what is left; say what is not in the file."""
        left = [str(p) for p in self._spilled.files]
        if left:
            emit(
                "error",
                "journal closed with rows only in its spill files (the file never came back)",
                spilled_rows=self._spilled.rows,
                spill_files=left,
                path=str(self._active),
                last_error=self._last_error,
            )
        if not rows:
            return
        spilled = self._spill(rows)
        if spilled is None:
            with self._lock:
                self._dropped_rows += len(rows)
        emit(
            "error",
            "journal closed with rows it could not write; saved to a spill file"
            if spilled
            else "journal closed with rows it could not write; they are lost",
            rows=len(rows),
            spill_file=str(spilled) if spilled else None,
            path=str(self._active),
            opened=opened,
            last_error=self._last_error,
        )

    def _spill_pending(self) -> None:
        """Failing for `SPILL_AFTER_S`: move the rows in memory to a spill file."""
        episode = self._episode
        if episode is None or time.monotonic() - episode[0] < SPILL_AFTER_S:
            return
        with self._lock:
            rows = [*self._urgent, *self._fixes]
            self._urgent, self._fixes = [], []
            self._in_flight = rows  # still pending while they are being written
        target: Path | None = None
        try:
            if rows:
                target = self._spilled.append([self._spill_line(row) for row in rows])
        finally:
            with self._lock:
                dropped = self._put_back_locked([] if target is not None else rows)
            if dropped:
                self._count_dropped(dropped)
        if rows and target is None:
            self._errors.error(
                "spill",
                "journal cannot write and no spill directory works; rows kept in memory",
                pending_rows=len(rows),
                directories=[str(d) for d in spill_directories(self._active, self._spill_dir)],
            )
        elif target is not None:
            self._errors.error(
                "spilled",
                "journal not writable; rows saved to a spill file until it is",
                spill_file=str(target),
                spilled_rows=self._spilled.rows,
                path=str(self._active),
                error=self._last_error,
            )

    def _replay(self) -> tuple[BaseException | None, BaseException | None]:
        """Write the spilled rows into the journal, oldest first.

        Returns the error that stopped it in cast rows and events (nothing newer
        may go first), and the one that stopped it in telemetry (the newer cast
        rows may, and the pass fails after them)."""
        if not self._spilled.files:
            return None, None
        old = list(self._spilled.files)
        raw, unreadable = self._spilled.take()
        rows: list[Row] = [tuple(row) for row in raw]
        groups = (
            [row for row in rows if row[0] not in self.bulk_kinds],
            [row for row in rows if row[0] in self.bulk_kinds],
        )
        left: list[Row] = []
        error: BaseException | None = None
        replayed = 0
        for group in groups:
            at = 0
            while at < len(group) and error is None:
                done, written, error = self._commit(group[at : at + MAX_TRANSACTION_ROWS])
                at += done
                replayed += written
                with self._lock:
                    self._rows_written += written
            left += group[at:]
        urgent_error = error if len(left) > len(groups[1]) else None
        if error is not None and replayed == 0:
            # Nothing moved: the files stay as they are, for the next try. Only
            # telemetry left: the newer cast rows in memory may still fit.
            return urgent_error, error
        if unreadable:
            self._count_dropped(unreadable)
        if left:  # the journal failed again: keep the rest in a spill file only
            self._spilled.rows = 0
            if self._spilled.append([self._spill_line(row) for row in left]) is None:
                with self._lock:
                    dropped = self._put_back_locked(left)
                if dropped:
                    self._count_dropped(dropped)
        else:
            self._spilled.rows = 0
        kept = self._spilled.forget(old)
        emit(
            "error" if left or kept else "warning",
            "journal replayed rows from its spill file",
            replayed_rows=replayed,
            rows_left=len(left),
            unreadable_lines=unreadable,
            spill_files=[str(p) for p in old],
            not_removed=[str(p) for p in kept],
            path=str(self._active),
        )
        return urgent_error, error
