"""Drum pulses that cannot be true: an encoder fault, as a pure judge fed each pulse.

A pulse sensor with a broken wire, a noisy cable or a pin left floating can
give thousands of pulses a second; counted, they move the "depth" by kilometres
(50,000 pulses at home read 7068 m). Two rules find them, from physics alone:

- **Faster than the drum can turn**: `window` intervals shorter, together,
  than the drum at full speed (the configured line speed at the lowest duty)
  would take, times `margin`.
- **More than a coasting allowance with the motor off**: a drum coasts a
  pulse or two after a stop; more than `coast_pulses` since the motor last
  started is not the drum.

Pure: fed the time and whether the motor runs; it never touches a pin, a
thread or a clock. The caller keeps it under its own lock.
"""

from __future__ import annotations

import math
from collections import deque

RATE_MARGIN = 3.0  # pulses this many times faster than full speed are not the drum
RATE_WINDOW = 4  # ... over this many intervals (one short interval is a bounce)


def max_pulse_rate(line_speed_m_s: float, lowest_duty: float, metres_per_pulse: float) -> float:
    """Pulses a second of the drum at full power (the line speed is at the duty)."""
    return line_speed_m_s / lowest_duty / metres_per_pulse


def coast_allowance(tolerance_m: float, metres_per_pulse: float) -> int:
    """Pulses a stopped drum may still give: what the count may drift and still agree."""
    return max(2, math.floor(tolerance_m / metres_per_pulse))


class EncoderJudge:
    def __init__(self, *, max_pulses_s: float, coast_pulses: int) -> None:
        if max_pulses_s <= 0 or coast_pulses < 0:
            raise ValueError("max_pulses_s must be > 0 and coast_pulses >= 0")
        self.max_pulses_s = max_pulses_s
        self.coast_pulses = coast_pulses
        self._min_span_s = RATE_WINDOW / (max_pulses_s * RATE_MARGIN)
        self._times: deque[float] = deque(maxlen=RATE_WINDOW + 1)
        self._coast = 0

    def motor_started(self) -> None:
        self._coast = 0
        self._times.clear()

    def pulse(self, now: float, running: bool) -> str | None:
        """One pulse at `now`; why it cannot be true, or None."""
        if not running:
            self._coast += 1
            if self._coast > self.coast_pulses:
                return (
                    f"{self._coast} pulses with the motor off "
                    f"(a coasting drum gives at most {self.coast_pulses})"
                )
            return None
        times = self._times
        times.append(now)
        if len(times) == times.maxlen and now - times[0] < self._min_span_s:
            rate = RATE_WINDOW / max(now - times[0], 1e-6)
            return (
                f"pulses at {rate:.0f}/s, faster than the drum can turn "
                f"({self.max_pulses_s:.1f}/s at full speed, x{RATE_MARGIN:g} allowed)"
            )
        return None
