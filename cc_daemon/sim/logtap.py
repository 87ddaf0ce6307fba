"""The daemon's log stream during a simulated run: to its file, and to the console.

This module owns `LogTap`, the file-like object structlog writes the in-process
daemon's JSON lines into. It must never raise into, nor print from, the daemon's
logging calls.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable
from typing import Any, TextIO


class LogTap:
    """The daemon's log stream: every line to the log file; info and up queued for the console.

    It is written from inside the daemon's logging calls, so it never raises
    and never prints: a failing log file is counted (`write_errors`) and the
    events for the console wait in a queue until the run's loop `drain`s them.
    A plain object with `write` and `flush` (all structlog needs), not an
    `io` stream: it has no finaliser to flush a file closed before it.
    """

    _QUIET = frozenset({"timestamp", "level", "logger", "event"})
    _SHOWN = frozenset({"info", "warning", "error", "critical"})

    def __init__(self, file: TextIO, clock: Callable[[], float]) -> None:
        self._file = file
        self._clock = clock
        self._partial = ""
        self._events: deque[tuple[float, dict[str, Any]]] = deque()
        self.write_errors = 0

    def write(self, text: str) -> int:
        try:
            self._file.write(text)
        except Exception:  # a full disk, a closed file: the daemon must carry on
            self.write_errors += 1
        try:
            self._partial += text
            *lines, self._partial = self._partial.split("\n")
            for line in lines:
                self._take(line)
        except Exception:  # never into the daemon's logging call
            self._partial = ""
        return len(text)

    def _take(self, line: str) -> None:
        try:
            event = json.loads(line)
        except ValueError:
            return
        if isinstance(event, dict) and event.get("level") in self._SHOWN:
            self._events.append((self._clock(), event))

    def flush(self) -> None:
        try:
            self._file.flush()
        except Exception:
            self.write_errors += 1

    def drain(self) -> list[tuple[float, dict[str, Any]]]:
        """The queued events (time from `clock`, the event), oldest first; the queue empties."""
        out: list[tuple[float, dict[str, Any]]] = []
        while self._events:
            out.append(self._events.popleft())
        return out

    @classmethod
    def describe(cls, event: dict[str, Any]) -> str:
        details = " ".join(f"{k}={v}" for k, v in event.items() if k not in cls._QUIET)
        level = event.get("level", "info")
        prefix = "daemon" if level == "info" else f"daemon {str(level).upper()}"
        return f"{prefix}: {event.get('event', '')}" + (f"  {details}" if details else "")
