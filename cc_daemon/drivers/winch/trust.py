"""Whether the GPIO winch's count can be believed, and where the probe is when it cannot.

`CountTrust` is a base of `gpio.GpioWinch`, on the loop side. Two things put the
count in doubt:

- **Pulses that cannot be true** (a storm): gpiozero's thread judges each pulse
  (`edges.EdgeCounting`, with `core.winch.encoder`) and on one that cannot be
  true stops the motor and freezes the count; this takes the verdict: the
  fault, and once a second at most a log line with the pulses not counted.
- **No pulse under power** (`core.winch.silence`, judged by the motion's
  guard): a dead encoder (the motor drew running current: it turned free)
  freezes the count as a storm does; a jam leaves it standing; without a
  trusted current sensor either may be true. Each leaves a depth estimate.

An encoder fault is treated as a disagreement of the witnesses (no `move_to`,
no home until both agree again, the cast stranded). While a depth estimate
stands, `depth_m` (and so the status, `R-L`'s depth, the journal and the log)
is its best estimate, never the stale count as if it were known; it stands
until a pulse is counted again or both witnesses agree on home. Its state is
set up by `GpioWinch.__init__`.
"""

from __future__ import annotations

import asyncio
import threading
from typing import TYPE_CHECKING, Any

import structlog

from cc_daemon.core.winch.drum import Drum
from cc_daemon.core.winch.encoder import RATE_WINDOW, EncoderJudge
from cc_daemon.core.winch.silence import DepthEstimate, Silence

_log = structlog.get_logger("cc_daemon.winch.gpio")


class CountTrust:
    """The encoder's faults and the depth estimate, on the loop (see the module docstring)."""

    _loop: asyncio.AbstractEventLoop
    _lock: threading.Lock
    _encoder_bad: str | None
    _estimate: DepthEstimate | None
    _ignored: int
    _ignored_told: int
    _summary: asyncio.TimerHandle | None
    _closed: bool

    drum: Drum
    _encoder: EncoderJudge

    if TYPE_CHECKING:  # GpioWinch's and HomeWitnessing's

        @property
        def line_m(self) -> float: ...

        def _fail(self, fault: str, **detail: Any) -> None: ...

        def _distrusted(self, reason: str, **detail: Any) -> None: ...

    @property
    def depth_m(self) -> float:
        """The probe's depth: the count's line, or the best estimate while one stands.
        An estimate is never reported as 0 m (R-P 0 says home, and only two witnesses
        may): at least one pulse of line, the least the count could have seen."""
        if self._estimate is not None:
            return max(self._estimate.best_m, self.drum.metres_per_pulse)
        return max(0.0, self.line_m)

    @property
    def depth_estimate(self) -> DepthEstimate | None:
        """The estimate standing (the count in doubt), if any."""
        return self._estimate

    def _where(self) -> dict[str, Any]:
        """The depth for a log line or a journal event: with an estimate, its range too."""
        estimate = self._estimate
        if estimate is None:
            return {"line_m": round(self.line_m, 3)}
        return {
            "line_m": round(self.depth_m, 3),
            "counted_line_m": round(estimate.counted_m, 3),
            "depth_low_m": round(estimate.low_m, 3),
            "depth_high_m": round(estimate.high_m, 3),
            "depth_by": "dead reckoning" if estimate.reckoned else "the count",
        }

    def _silent_drum(self, silence: Silence, **detail: Any) -> None:
        """The no-pulse rule broke: the motor stops, the estimate stands, and a dead
        encoder (the motor turned free) is an encoder fault."""
        self._estimate = silence.estimate
        if not silence.encoder_dead:
            self._fail(silence.text, cause=silence.cause.value, **detail)
            return
        with self._lock:  # from now on each pulse is ignored: the count is not trusted
            self._encoder_bad = self._encoder_bad or silence.text
        self._distrusted(silence.text, cause=silence.cause.value, **detail)
        self._summarise_ignored()

    def _encoder_faulted(self, reason: str) -> None:
        """Pulses that cannot be true: the count is frozen, and before the judge could
        tell, up to its window (or the coasting allowance) of them may have been
        counted. The depth is an estimate from here: the count, give or take those;
        a haul the operator runs moves it as any run without pulses does."""
        if self._estimate is None:
            line = self.line_m
            doubt = (max(RATE_WINDOW, self._encoder.coast_pulses) + 1) * self.drum.metres_per_pulse
            self._estimate = DepthEstimate(
                best_m=max(0.0, line),
                low_m=max(0.0, line - doubt),
                high_m=max(0.0, line) + doubt,
                counted_m=line,
                reckoned=False,
            )
        self._distrusted(f"encoder fault: {reason}; the count is no longer trusted")
        self._summarise_ignored()

    def _summarise_ignored(self) -> None:
        """While the encoder is faulted: once a second at most, the pulses not counted."""
        if self._summary is not None:  # one chain of summaries, however many verdicts
            self._summary.cancel()
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
