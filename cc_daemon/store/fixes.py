"""Telemetry fixes in the journal: their rows, thinned to a rate.

This module owns what happens to a fix between the daemon's loop and the writer:
its row (stamped as every row is), the thinning that bounds what a babbling
autopilot can do (`thinning.FixThinner`: the latest fix of each interval kept,
the others counted in a `telemetry_thinned` event at most every minute), the
release of a held fix by the writer thread once its interval is over, and the
last held fix and count at close. `journal.Journal` builds on it for everything
else: casts, samples, events, sonar readings, and the SQL.
"""

from __future__ import annotations

import time
from abc import abstractmethod
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from cc_daemon.core.protocol import StartMeasuring, Telemetry
from cc_daemon.store.buffer import FIX
from cc_daemon.store.thinning import FixThinner, buffer_rows
from cc_daemon.store.writer import BufferedWriter


class FixJournal(BufferedWriter):
    """The fixes' part of `journal.Journal` (see there for the threads' rules)."""

    def __init__(
        self,
        path: Path,
        *,
        monotonic: Callable[[], float] = time.monotonic,
        telemetry_rate_hz: float | None = None,
        max_buffered_rows: int | None = None,
        **writer: Any,
    ) -> None:
        """`telemetry_rate_hz` None keeps every fix (a library default; the daemon
        always passes its `store.telemetry_rate_hz`). `max_buffered_rows` None
        sizes the buffer from the rate (`buffer_rows`), or 100,000 rows unthinned.
        """
        self._thinner = FixThinner(telemetry_rate_hz) if telemetry_rate_hz is not None else None
        self._sized_by_rate = max_buffered_rows is None and telemetry_rate_hz is not None
        if max_buffered_rows is None:
            max_buffered_rows = (
                100_000 if telemetry_rate_hz is None else buffer_rows(telemetry_rate_hz)
            )
        super().__init__(path, max_buffered_rows=max_buffered_rows, **writer)
        self._monotonic = monotonic

    # What the journal provides.

    @abstractmethod
    def record_event(self, kind: str, **detail: object) -> None:
        """Journal an event (`journal.Journal`): the thinning's summaries are events."""

    @abstractmethod
    def _clock_synced(self, mono: float) -> int:
        """Whether the wall clock was synchronised at `mono` (`journal.Journal`)."""

    # ------------------------------------------------- loop-thread recording

    def record_fix(
        self,
        msg: Telemetry | StartMeasuring,
        *,
        ap_time_s: int | None = None,
        ap_time_order: str | None = None,
    ) -> None:
        """A telemetry fix (`P-T`) or a start-measuring frame (`P-M`), as received,
        with the autopilot's clock as decoded in byte order `ap_time_order`."""
        self._record_fix(msg, ap_time_s, ap_time_order, 0)

    def record_fixes(
        self,
        msgs: Sequence[Telemetry],
        *,
        decode: Callable[[int], int] | None = None,
        ap_time_order: str | None = None,
    ) -> None:
        """Fixes read together (a run of `P-T` in one read), in order: `record_fix`
        for each, their autopilot times decoded by `decode`. Thinned, they share one
        instant, of which only the latest fix is kept: the others are counted as
        thinned at once, without a row ever made for them (a flood's hot path)."""
        unthinned = self._thinner is None
        for msg in msgs if unthinned else msgs[-1:]:
            ap_time_s = None if decode is None else decode(msg.timestamp_s)
            self._record_fix(msg, ap_time_s, ap_time_order, 0 if unthinned else len(msgs) - 1)

    def _record_fix(
        self,
        msg: Telemetry | StartMeasuring,
        ap_time_s: int | None,
        ap_time_order: str | None,
        replaced: int,
    ) -> None:
        """`replaced`: fixes of the same instant before `msg`, which its row replaces
        (a thinned journal only: `record_fixes` passes none to an unthinned one)."""
        try:
            mono = self._monotonic()
            ts, lon, lat, alt, sonar, confidence, *mode = msg  # mode: the 26-byte M's
            row = (
                FIX,
                mono,
                self._wall(),
                self._clock_synced(mono),
                msg.frame,
                ts,
                lon,
                lat,
                alt,
                sonar,
                confidence,
                mode[0] if mode else None,
                ap_time_s,
                ap_time_order,
            )
            thinner = self._thinner
            if thinner is None:
                self._append(row)
                return
            with self._lock:
                first = not thinner.holding  # the writer may sleep with no deadline
                ready = thinner.offer(row, mono, replaced)
                thinned = thinner.report(mono)
            if ready is not None:
                self._append(ready)
            elif first:
                self._wake.set()  # to release the held fix once its interval is over
            if thinned:
                self._report_thinned(thinned)
        except Exception as exc:
            self._errors.error("record_fix", "journal could not record a fix", error=repr(exc))

    def set_telemetry_rate(self, rate_hz: float) -> None:
        """Thin telemetry to `rate_hz` from now on (a reload); a journal made without
        a rate starts thinning. A buffer sized from the rate is resized with it."""
        with self._lock:
            if self._thinner is None:
                self._thinner = FixThinner(rate_hz)
                self._sized_by_rate = True
            else:
                self._thinner.set_rate(rate_hz)
            if self._sized_by_rate:
                self._max_rows = buffer_rows(rate_hz)

    def _report_thinned(self, count: int) -> None:
        assert self._thinner is not None
        self.record_event(
            "telemetry_thinned",
            dropped=count,
            rate_hz=self._thinner.rate_hz,
            note="fixes beyond the journal's telemetry rate: the latest of each interval is kept",
        )

    def _holds_rows(self) -> bool:
        # A held fix is released by a pass once its interval is over: keep the tick.
        with self._lock:
            return self._thinner is not None and self._thinner.holding

    def _before_pass(self) -> None:
        # The writer thread: a held fix whose interval is over goes to the buffer.
        if self._thinner is None:
            return
        try:
            mono = self._monotonic()
            with self._lock:
                ready = self._thinner.due(mono)
            if ready is not None:
                self._buffer_row(ready)
        except Exception as exc:
            self._errors.error("held_fix", "journal could not release a held fix", error=repr(exc))

    def close(self, timeout: float = 5.0) -> None:
        """As `BufferedWriter.close`, after the last held fix and the count of thinned ones."""
        if not self._closed and self._thinner is not None:
            try:
                with self._lock:
                    held = self._thinner.take()
                    thinned = self._thinner.report(self._monotonic(), everything=True)
                if held is not None:
                    self._append(held)
                if thinned:
                    self._report_thinned(thinned)
            except Exception as exc:
                self._errors.error("close", "journal could not keep its last fix", error=repr(exc))
        super().close(timeout)
