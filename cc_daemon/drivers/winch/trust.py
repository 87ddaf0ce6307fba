"""Whether the GPIO winch's count can be believed: an encoder fault, on the loop side.

`CountTrust` is a base of `gpio.GpioWinch`. gpiozero's thread judges each pulse
(`edges.EdgeCounting`, with `core.winch.encoder`) and, on a pulse that cannot
be true, stops the motor and freezes the count; this takes the verdict on the
loop: the fault, treated as a disagreement of the witnesses (no `move_to`, no
home until both agree again), and once a second at most a log line with the
pulses not counted. Its state is set up by `GpioWinch.__init__`.
"""

from __future__ import annotations

import asyncio
import threading
from typing import TYPE_CHECKING

import structlog

_log = structlog.get_logger("cc_daemon.winch.gpio")


class CountTrust:
    """The encoder's faults, on the loop (see the module docstring)."""

    _loop: asyncio.AbstractEventLoop
    _lock: threading.Lock
    _encoder_bad: str | None
    _ignored: int
    _ignored_told: int
    _summary: asyncio.TimerHandle | None
    _closed: bool

    if TYPE_CHECKING:  # HomeWitnessing's

        def _distrusted(self, reason: str) -> None: ...

    def _encoder_faulted(self, reason: str) -> None:
        self._distrusted(f"encoder fault: {reason}; the count is no longer trusted")
        self._summarise_ignored()

    def _summarise_ignored(self) -> None:
        """While the encoder is faulted: once a second at most, the pulses not counted."""
        self._summary = None
        with self._lock:
            ignored, bad = self._ignored, self._encoder_bad
        if ignored > self._ignored_told:
            _log.warning(
                "winch encoder fault: pulses not counted",
                pulses=ignored - self._ignored_told,
                since_fault=ignored,
                fault=bad,
            )
            self._ignored_told = ignored
        if bad is not None and not self._closed:
            self._summary = self._loop.call_later(1.0, self._summarise_ignored)
