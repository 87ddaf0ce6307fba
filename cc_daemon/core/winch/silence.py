"""A drum that gives no pulse under power: a jam or a dead encoder, and where the probe is
(pure).

When the motor has run `stall_timeout_s` without a drum pulse, the count stays
where the last pulse left it, but the probe may not have: a jammed drum did not
turn (the count is right), a dead encoder (a cut pulse wire, a sensor gone) saw a
drum that did (the count is stale by everything the motor wound meanwhile). The
motor current tells them apart where the winch has a trusted sensor:

- a motor drawing running current (at least `TURNING_MIN_A`, at most
  `max_current_a`) turned free: **the encoder is dead**, and the probe is where
  dead reckoning puts it (the line speed at the duties it ran, for the time it ran);
- a motor drawing more than `max_current_a` pulled against a **jam**: the count
  stands;
- a motor drawing less than `TURNING_MIN_A` may have had no power (or the
  sensor reads low): the count may stand, or not;
- with no trusted current sensor nothing tells: a jammed drum or a dead encoder.

Whatever the verdict, the probe is somewhere in a range (`DepthEstimate`):
hauling in, between the counted depth less the run (times `RUN_MARGIN`, a drum
faster than configured) and the counted depth; paying out, the other way. The
best estimate is dead reckoning when the current says the drum turned, the
counted depth when it may not have. Numbers and times in, verdicts out: it
never touches a pin, a thread or a clock.
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass, replace
from enum import Enum

from cc_daemon.core.winch.sensors import TURNING_MIN_A

RUN_MARGIN = 1.5  # the drum may have run this much faster than line_speed_m_s says


@dataclass(frozen=True, slots=True)
class DepthEstimate:
    """Where the probe is when the count cannot say for sure: `best_m` within
    [`low_m`, `high_m`]; `counted_m` is what the (frozen) count says."""

    best_m: float
    low_m: float
    high_m: float
    counted_m: float
    reckoned: bool  # best_m is dead reckoning (the drum turned), not the count

    @classmethod
    def counted(cls, line_m: float) -> DepthEstimate:
        """No doubt yet: the count's line (never above the surface)."""
        depth = max(0.0, line_m)
        return cls(depth, depth, depth, line_m, reckoned=False)

    def after_run(self, direction: int, run_m: float, *, turned: bool) -> DepthEstimate:
        """After the motor ran `run_m` of line (by the line speed at its duties) with
        no pulse counted: `direction` +1 paying out, -1 hauling in; `turned`: the
        current says the drum turned, so the best estimate moves by the run."""
        if direction == 0 or run_m <= 0:
            return self
        spread = run_m * RUN_MARGIN
        if direction < 0:
            low, high = max(0.0, self.low_m - spread), self.high_m
            best = max(0.0, self.best_m - run_m) if turned else self.best_m
        else:
            low, high = self.low_m, self.high_m + spread
            best = self.best_m + run_m if turned else self.best_m
        return replace(self, best_m=best, low_m=low, high_m=high, reckoned=self.reckoned or turned)

    def describe(self) -> str:
        how = "by dead reckoning" if self.reckoned else "if the drum did not turn"
        return (
            f"the probe is between {self.low_m:.2f} and {self.high_m:.2f} m, best estimate "
            f"{self.best_m:.2f} m ({how}; {self.counted_m:.2f} m counted)"
        )


class Cause(Enum):
    ENCODER_DEAD = "encoder dead"  # the motor turned free: the pulses are what died
    JAM = "jam"  # the motor pulled against something: the count stands
    NO_POWER = "no power"  # too little current to turn: no power, or a sensor reading low
    UNKNOWN = "unknown"  # no trusted current sensor: a jam or a dead encoder


@dataclass(frozen=True, slots=True)
class Silence:
    """The no-pulse rule's verdict: what the silence was, and where the probe is."""

    cause: Cause
    text: str  # for the operator: the fault the winch reports
    estimate: DepthEstimate

    @property
    def encoder_dead(self) -> bool:
        return self.cause is Cause.ENCODER_DEAD


def turning(currents: Sequence[float], max_current_a: float) -> bool | None:
    """Whether a motor drawing these currents turned free (None: no reading to say)."""
    if not currents:
        return None
    return TURNING_MIN_A <= statistics.median(currents) <= max_current_a


def judge_silence(
    *,
    quiet_s: float,
    stall_timeout_s: float,
    max_current_a: float,
    currents: Sequence[float] | None,
    base: DepthEstimate,
    direction: int,
    run_m: float,
) -> Silence:
    """The verdict on `quiet_s` without a pulse under power.

    `currents`: the trusted sensor's readings meanwhile (None: no trusted sensor);
    `base`: where the probe was at the last pulse (or the estimate standing from an
    earlier silence); `run_m`: the line the motor would have wound meanwhile (the
    line speed at each duty, times the time at it)."""
    head = f"no drum pulse for {quiet_s:.1f} s (stall_timeout_s {stall_timeout_s:g})"
    if not currents:
        estimate = base.after_run(direction, run_m, turned=False)
        return Silence(
            Cause.UNKNOWN,
            f"stall: {head}: a jammed drum or a dead encoder; no current sensor to tell; "
            f"{estimate.describe()}",
            estimate,
        )
    amps = statistics.median(currents)
    if amps > max_current_a:
        return Silence(
            Cause.JAM,
            f"stall: {head} while the motor drew {amps:.2f} A, above max_current_a "
            f"{max_current_a:g} A: a jammed drum, at {base.best_m:.2f} m",
            base,
        )
    if amps < TURNING_MIN_A:
        estimate = base.after_run(direction, run_m, turned=False)
        return Silence(
            Cause.NO_POWER,
            f"stall: {head} while the motor drew only {amps:.2f} A: no power reached it "
            f"(a fuse, the H-bridge, a motor wire), or a dead encoder and a current sensor "
            f"reading low; {estimate.describe()}",
            estimate,
        )
    estimate = base.after_run(direction, run_m, turned=True)
    return Silence(
        Cause.ENCODER_DEAD,
        f"encoder dead: {head} while the motor drew {amps:.2f} A (turning, not jammed); "
        f"the count is no longer trusted: {estimate.describe()}",
        estimate,
    )
