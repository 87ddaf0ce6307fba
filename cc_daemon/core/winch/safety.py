"""The time-based safety rules of one winch motion, as a pure model fed the time.

A motion is watched for three things: a drum that stops turning (no pulse for
`stall_timeout_s`), a motor that draws more than `max_current_a` for longer than
`overcurrent_s`, and a haul home that has not met the limit switch by its
deadline. `check` says which rule broke, in words for the operator, or None.
For the no-pulse rule it also keeps what the motor did meanwhile (the duty it
ran at, the current it drew) and leaves the verdict in `silence`: a jam or a
dead encoder, and where the probe is (`core.winch.silence`). It never touches a
pin or a clock: the caller stops the motor.
"""

from __future__ import annotations

from dataclasses import dataclass

from cc_daemon.core.winch.silence import DepthEstimate, Silence, judge_silence, turning


@dataclass(frozen=True, slots=True)
class Limits:
    stall_timeout_s: float
    max_current_a: float
    overcurrent_s: float


class MotionGuard:
    """One motion's rules. `direction` is the motor's (+1 paying out, -1 hauling in);
    `full_speed_m_s` the line speed at duty 1 in that direction; `prior` the depth
    estimate standing when the motion began (an earlier silence), if any."""

    def __init__(
        self,
        limits: Limits,
        *,
        started_at: float,
        home_deadline: float | None,
        direction: int,
        full_speed_m_s: float,
        prior: DepthEstimate | None = None,
    ) -> None:
        self.limits = limits
        self.started_at = started_at
        self.home_deadline = home_deadline
        self.direction = direction
        self.full_speed_m_s = full_speed_m_s
        self._prior = prior
        self._last_pulse = started_at
        self._last_check = started_at
        self._duty_s = 0.0  # duty x seconds under power since the last pulse (or verdict)
        self._last_duty = 0.0
        self._currents: list[float] = []  # the trusted readings since the last pulse
        self._over_since: float | None = None
        self.peak_current_a = 0.0
        self.silence: Silence | None = None  # the no-pulse rule's verdict, once broken

    def pulse(self, now: float) -> None:
        """A counted pulse: the drum turns and the count says where it is."""
        self._last_pulse = max(self._last_pulse, now)
        self._duty_s = 0.0
        self._currents.clear()
        self._prior = None

    def check(
        self, now: float, current_a: float | None, line_m: float, *, duty: float
    ) -> str | None:
        """At `now`, the motor having run at `duty` since the last check, drawing
        `current_a` (None: no trusted sensor), with `line_m` counted."""
        limits = self.limits
        self._ran(now, duty)
        if current_a is not None:
            self.peak_current_a = max(self.peak_current_a, current_a)
            self._currents.append(current_a)
        quiet = now - self._last_pulse
        if quiet > limits.stall_timeout_s:
            self.silence = judge_silence(
                quiet_s=quiet,
                stall_timeout_s=limits.stall_timeout_s,
                max_current_a=limits.max_current_a,
                currents=self._currents if current_a is not None else None,
                base=self._prior or DepthEstimate.counted(line_m),
                direction=self.direction,
                run_m=self.full_speed_m_s * self._duty_s,
            )
            self._doubt(self.silence.estimate)
            return self.silence.text
        if current_a is not None:
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

    def stopped(self, now: float) -> DepthEstimate | None:
        """The motor stopped at `now` (any stop: a verdict, the switch, an operator).
        With a depth estimate standing and no pulse counted since, where the probe
        has gone meanwhile; None: the count says where it is."""
        if self._prior is None:
            return None
        self._ran(now, self._last_duty)
        self._last_duty = 0.0  # stopped: a second call adds nothing
        turned = turning(self._currents, self.limits.max_current_a)
        if turned is None:  # no reading: as the last verdict said (turning free, or unknown)
            turned = self._prior.reckoned
        run_m = self.full_speed_m_s * self._duty_s
        self._doubt(self._prior.after_run(self.direction, run_m, turned=turned))
        return self._prior

    def _ran(self, now: float, duty: float) -> None:
        """The motor ran at `duty` from the last check (or pulse) to `now`."""
        self._duty_s += duty * max(0.0, now - max(self._last_check, self._last_pulse))
        self._last_check = now
        self._last_duty = duty

    def _doubt(self, estimate: DepthEstimate) -> None:
        """The estimate standing from here: the run so far is in it."""
        self._prior = estimate
        self._duty_s = 0.0
        self._currents.clear()
