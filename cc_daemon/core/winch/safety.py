"""The time-based safety rules of one winch motion, as a pure model fed the time.

A motion is watched for three things: a drum that stops turning (no pulse for
`stall_timeout_s`), a motor that draws more than `max_current_a` for longer than
`overcurrent_s`, and a haul home that has not met the limit switch by its
deadline. `check` says which rule broke, in words for the operator, or None.
It never touches a pin or a clock: the caller stops the motor.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Limits:
    stall_timeout_s: float
    max_current_a: float
    overcurrent_s: float


class MotionGuard:
    def __init__(self, limits: Limits, *, started_at: float, home_deadline: float | None) -> None:
        self.limits = limits
        self.started_at = started_at
        self.home_deadline = home_deadline
        self._last_pulse = started_at
        self._over_since: float | None = None
        self.peak_current_a = 0.0

    def pulse(self, now: float) -> None:
        self._last_pulse = max(self._last_pulse, now)

    def check(self, now: float, current_a: float | None, line_m: float) -> str | None:
        limits = self.limits
        quiet = now - self._last_pulse
        if quiet > limits.stall_timeout_s:
            return (
                f"stall: no drum pulse for {quiet:.1f} s "
                f"(stall_timeout_s {limits.stall_timeout_s:g}) at {line_m:.2f} m"
            )
        if current_a is not None:
            self.peak_current_a = max(self.peak_current_a, current_a)
            if current_a > limits.max_current_a:
                if self._over_since is None:
                    self._over_since = now
                elif now - self._over_since > limits.overcurrent_s:
                    return (
                        f"stall: motor current {current_a:.2f} A above max_current_a "
                        f"{limits.max_current_a:g} A for {now - self._over_since:.2f} s "
                        f"at {line_m:.2f} m"
                    )
            else:
                self._over_since = None
        if self.home_deadline is not None and now > self.home_deadline:
            return (
                f"home not reached: the limit switch is still open "
                f"{now - self.started_at:.1f} s into the haul, with {line_m:.2f} m counted out"
            )
        return None
