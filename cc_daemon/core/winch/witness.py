"""Home, as two witnesses say it: the line count and the limit switch (pure).

It owns the rules of docs/gpio-winch.md "Home has two witnesses": the probe is
home only when the count is within `tolerance_m` of zero *and* the switch has
been closed continuously for `settle_s`; when the two contradict each other it
names the disagreement with both figures. One faulty sensor can never declare
the probe home by itself. Numbers and times in, verdicts out: it never touches
a pin, a thread or a clock.
"""

from __future__ import annotations

from dataclasses import dataclass

# A descent whose switch is still closed this many pulses out never left the block.
LEAVE_PULSES = 3


@dataclass(frozen=True, slots=True)
class Witnesses:
    tolerance_m: float  # winch.gpio.count_tolerance_m
    settle_s: float  # winch.gpio.switch_settle_s
    leave_m: float  # line out by which a descending probe has surely opened the switch

    def disagreement(self, line_m: float, switch_closed: bool, direction: int) -> str | None:
        """Why the count and the switch contradict each other, or None.

        `direction` is the motor's: +1 paying out, -1 hauling in, 0 stopped.
        """
        if switch_closed:
            if abs(line_m) > self.tolerance_m:
                return (
                    f"witnesses disagree: the limit switch is closed with {line_m:.2f} m "
                    f"counted out (count_tolerance_m {self.tolerance_m:g})"
                )
            if direction > 0 and line_m >= self.leave_m:
                return (
                    f"witnesses disagree: the limit switch is still closed {line_m:.2f} m "
                    "into the descent (the probe never left the block, or the switch is stuck)"
                )
            return None
        if direction < 0 and line_m < -self.tolerance_m:
            return (
                f"witnesses disagree: hauled {-line_m:.2f} m past the count's zero and the "
                f"limit switch is still open (count_tolerance_m {self.tolerance_m:g})"
            )
        return None
